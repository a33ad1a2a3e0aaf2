"""Bad requests get a 4xx with a one-line JSON error naming the field, in the scene-file words."""

from __future__ import annotations

import http.client
import json
import urllib.parse

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from .conftest import small_scene


def _post(url, body: bytes, headers=None):
    u = urllib.parse.urlsplit(url)
    c = http.client.HTTPConnection(u.hostname, u.port, timeout=120)
    try:
        c.request("POST", "/v1/render", body=body, headers={"Content-Type": "application/json", **(headers or {})})
        r = c.getresponse()
        return r.status, r.headers, r.read()
    finally:
        c.close()


def _error(status, data):
    assert 400 <= status < 500, (status, data[:300])
    doc = json.loads(data)
    assert set(doc) == {"error"} and "\n" not in doc["error"] and "Traceback" not in doc["error"]
    return doc["error"]


def _scene_file_error(mapping, tmp_path, capsys):
    """What ``skynav scene`` says of the same mapping as a scene file (its one line, prefix removed)."""
    from skynav.cli import main

    f = tmp_path / "bad.yaml"
    f.write_text(json.dumps(mapping))
    capsys.readouterr()
    assert main(["scene", str(f)]) == 2
    return capsys.readouterr().err.strip().removeprefix("skynav: error: ")


@pytest.mark.parametrize("change, field", [
    ({"camera": {"preset": "paper", "width": -3}}, "camera.width"),
    ({"attitude": {"point_at": "pluto"}}, "pluto"),
    ({"epoch": "yesterday"}, "epoch"),
    ({"render": {"seed": "one"}}, "render.seed"),
    ({"colour": 1}, "colour"),
])
def test_scene_errors_use_the_scene_file_words(server, tmp_path, capsys, change, field):
    mapping = {**small_scene(), **change}
    status, _, data = _post(server.url, json.dumps(mapping).encode())
    msg = _error(status, data)
    assert field in msg
    assert msg == _scene_file_error(mapping, tmp_path, capsys)


@pytest.mark.parametrize("body, field", [
    (b"{", "request body"),
    (b"[1, 2]", "request body"),
    (b'{"epoch": NaN}', "request body"),
    (b"\xff\xfe", "request body"),
    (json.dumps({**small_scene(), "outputs": ["gif"]}).encode(), "outputs"),
    (json.dumps({**small_scene(), "outputs": ["screen_png"]}).encode(), "facility"),
    (json.dumps({**small_scene(), "outputs": []}).encode(), "outputs"),
    (json.dumps({**small_scene(), "outputs": ["png", "png"]}).encode(), "outputs"),
    (json.dumps(small_scene(camera={"width": 8192, "height": 8192})).encode(), "--max-camera-pixels"),
])
def test_malformed_requests(server, body, field):
    status, _, data = _post(server.url, body)
    assert field in _error(status, data)


def test_size_and_type_bounds(server):
    status, _, data = _post(server.url, b"{" + b" " * 70000 + b"}")
    assert status == 413 and "--max-request-bytes" in _error(status, data)
    status, _, data = _post(server.url, b"<xml/>", headers={"Content-Type": "application/xml"})
    assert status == 415 and "Content-Type" in _error(status, data)
    u = urllib.parse.urlsplit(server.url)
    c = http.client.HTTPConnection(u.hostname, u.port, timeout=30)
    c.request("DELETE", "/v1/render")
    r = c.getresponse()
    assert r.status == 405 and "Method Not Allowed" in _error(r.status, r.read())


def test_the_client_gets_the_one_liner_and_keeps_its_connection(server):
    """A refused request through ``Client`` (a body over the bound, sent whole before the server
    refuses it) raises the server's line with its status; the next request on the same kept-alive
    connection gets its frame."""
    from skynav.service import Client, ServiceError

    c = Client(server.url)
    scene = small_scene(size=64)
    want = c.render(scene, outputs=("png",)).png
    for size in (70_000, 3_000_000):
        with pytest.raises(ServiceError) as e:
            c.render({**scene, "junk": "x" * size}, outputs=("png",))
        assert e.value.status == 413 and "--max-request-bytes" in str(e.value) and "\n" not in str(e.value)
        assert c.render(scene, outputs=("png",)).png == want


_json = st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False, allow_infinity=False)
                     | st.text(max_size=12),
                     lambda kids: st.lists(kids, max_size=4) | st.dictionaries(st.text(max_size=10), kids, max_size=4),
                     max_leaves=12)
_keys = st.sampled_from(["epoch", "observer", "attitude", "camera", "visibility", "render", "outputs", "seed"])


@st.composite
def _requests(draw):
    kind = draw(st.integers(0, 3))
    if kind == 0:     # arbitrary bytes
        return draw(st.binary(max_size=200))
    if kind == 1:     # arbitrary JSON
        return json.dumps(draw(_json)).encode()
    mapping = small_scene(size=32)   # a real scene with a few keys replaced or removed
    for key in draw(st.lists(_keys, max_size=3)):
        if draw(st.booleans()):
            mapping.pop(key, None)
        else:
            mapping[key] = draw(_json)
    if kind == 3 and isinstance(mapping.get("camera"), dict):
        mapping["camera"][draw(st.sampled_from(["width", "height", "exposure_s", "preset", "fov_deg"]))] = draw(_json)
    return json.dumps(mapping).encode()


@settings(max_examples=1000, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(body=_requests())
def test_fuzz_never_a_5xx(server, body):
    status, _, data = _post(server.url, body)
    if status != 200:
        _error(status, data)


def test_still_answering_after_the_fuzz(client):
    assert client.health()["status"] == "ok"
