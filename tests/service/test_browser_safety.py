"""A web page cannot use the server: JSON bodies only, Host names checked, foreign origins refused.

Against a real server on loopback, with raw HTTP requests as a browser would send them (a form
POST, a text/plain POST, a page rebound to 127.0.0.1, a preflight), and with ``--allow-origin``.
"""

from __future__ import annotations

import http.client
import json
import urllib.parse

import pytest

from .conftest import small_scene, start_server


def _send(url, method="POST", body=b"", headers=None):
    u = urllib.parse.urlsplit(url)
    c = http.client.HTTPConnection(u.hostname, u.port, timeout=120)
    try:
        c.putrequest(method, "/v1/render" if method != "GET" else "/v1/health", skip_host=True)
        for k, v in {"Host": f"127.0.0.1:{u.port}", **(headers or {})}.items():
            c.putheader(k, v)
        c.putheader("Content-Length", str(len(body)))
        c.endheaders(body)
        r = c.getresponse()
        return r.status, r.headers, r.read()
    finally:
        c.close()


def _line(data):
    doc = json.loads(data)
    assert set(doc) == {"error"} and "\n" not in doc["error"]
    return doc["error"]


BODY = json.dumps({**small_scene(size=64), "outputs": ["truth"]}).encode()


@pytest.mark.parametrize("ctype", [None, "application/x-www-form-urlencoded", "text/plain", "multipart/form-data"])
def test_only_json_bodies(server, ctype):
    status, _, data = _send(server.url, body=BODY, headers={} if ctype is None else {"Content-Type": ctype})
    assert status == 415 and "application/json" in _line(data)


@pytest.mark.parametrize("port", [True, False])
@pytest.mark.parametrize("name", ["127.0.0.1", "localhost", "LOCALHOST", "[::1]"])
def test_the_names_the_server_listens_on_are_served(server, name, port):
    host = f"{name}:{urllib.parse.urlsplit(server.url).port}" if port else name
    status, _, data = _send(server.url, body=BODY, headers={"Host": host, "Content-Type": "application/json"})
    assert status == 200, data[:300]


@pytest.mark.parametrize("host", ["attacker.example", "attacker.example:8765", "127.0.0.1.nip.io", ""])
def test_a_foreign_host_is_refused(server, host):
    for method in ("POST", "GET"):
        status, _, data = _send(server.url, method, body=BODY if method == "POST" else b"",
                                headers={"Host": host, "Content-Type": "application/json"})
        assert status == 400 and _line(data).startswith("Host ")


def test_a_foreign_origin_is_refused_and_no_cors(server):
    headers = {"Content-Type": "application/json", "Origin": "https://attacker.example"}
    status, hdrs, data = _send(server.url, body=BODY, headers=headers)
    assert status == 403 and "--allow-origin" in _line(data)
    assert "access-control-allow-origin" not in {k.lower() for k in hdrs}
    status, hdrs, _ = _send(server.url, "OPTIONS", headers={"Origin": "https://attacker.example",
                                                            "Access-Control-Request-Method": "POST"})
    assert status == 403 and "access-control-allow-origin" not in {k.lower() for k in hdrs}


def test_an_allowed_origin_gets_cors_and_others_still_refused():
    s = start_server("--allow-origin", "https://lab.example")
    try:
        ok = {"Content-Type": "application/json", "Origin": "https://lab.example"}
        status, hdrs, data = _send(s.url, body=BODY, headers=ok)
        assert status == 200 and hdrs["access-control-allow-origin"] == "https://lab.example"
        status, hdrs, _ = _send(s.url, "OPTIONS", headers={"Origin": "https://lab.example",
                                                           "Access-Control-Request-Method": "POST",
                                                           "Access-Control-Request-Headers": "content-type"})
        assert status == 200 and hdrs["access-control-allow-origin"] == "https://lab.example"
        status, _, data = _send(s.url, body=BODY, headers={**ok, "Origin": "https://other.example"})
        assert status == 403
    finally:
        s.stop()
