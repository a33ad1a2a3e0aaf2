"""SPICE kernels through the service: only names inside the server's --data-dir folders, the
truth keeps the name as given and the file's SHA-256, a bad kernel is a one-line 400 and the
service answers on (a real server on loopback)."""

from __future__ import annotations

import hashlib
import json
import os

import numpy as np
import pytest

sp = pytest.importorskip("spiceypy")

from .conftest import small_scene, start_server  # noqa: E402
from .test_bad_requests import _error, _post  # noqa: E402


def _spk(path, r0, v, t0, body=-999):
    """A Type 13 SPK of uniform motion about the barycentre, a day either side of ``t0``."""
    t = t0 + np.arange(-86400.0, 86400.0 + 1.0, 3600.0)
    states = np.hstack([r0 + np.outer(t - t0, v), np.tile(v, (len(t), 1))])
    h = sp.spkopn(str(path), "skynav test", 0)
    sp.spkw13(h, body, 0, "J2000", t[0], t[-1], "uniform", 3, len(t), states, t)
    sp.spkcls(h)


@pytest.fixture(scope="module")
def tree(tmp_path_factory):
    from skynav.scenes.timescales import tdb_seconds

    root = tmp_path_factory.mktemp("kernels")
    data, secret = root / "data", root / "secret"
    data.mkdir()
    secret.mkdir()
    m = small_scene()
    t0 = float(tdb_seconds(m["epoch"]))
    r0, v = np.array(m["observer"]["position_km"]), np.array(m["observer"]["velocity_km_s"])
    _spk(data / "craft.bsp", r0, v, t0)
    _spk(secret / "craft.bsp", r0 + 1e4, v, t0)
    (data / "broken.bsp").write_bytes(b"DAF/SPK " + b"\0" * 100)
    os.symlink(secret / "craft.bsp", data / "outside.bsp")
    os.mkfifo(data / "fifo.bsp")
    return root


@pytest.fixture(scope="module")
def kernel_server(tree):
    s = start_server("--data-dir", str(tree / "data"))
    yield s
    s.stop()


def _scene(kernels, body="-999"):
    m = small_scene(size=64)
    m["observer"] = {"spice": {"kernels": kernels, "body": body}}
    m["outputs"] = ["truth"]
    return m


def test_a_kernel_inside_renders_and_the_truth_keeps_its_name_and_digest(kernel_server, tree):
    status, _, data = _post(kernel_server.url, json.dumps(_scene(["craft.bsp"])).encode())
    assert status == 200, data[:300]
    truth = json.loads(data)
    # the SPK's uniform motion at the epoch is the preset's state (1 mm: float64 of 1e8 km)
    np.testing.assert_allclose(truth["observer"]["position_km"], small_scene()["observer"]["position_km"], atol=1e-6)
    sha = hashlib.sha256((tree / "data" / "craft.bsp").read_bytes()).hexdigest()
    assert truth["data_files"] == [{"key": "observer.spice.kernels", "name": "craft.bsp", "sha256": sha}]
    assert str(tree) not in data.decode() and os.path.realpath(tree) not in data.decode()


@pytest.mark.parametrize("name", ["missing.bsp", "outside.bsp", "fifo.bsp", "../secret/craft.bsp", "/etc/hosts",
                                  "ABSOLUTE"])
def test_every_other_name_gets_the_same_generic_400(kernel_server, tree, name):
    name = str(tree / "secret" / "craft.bsp") if name == "ABSOLUTE" else name
    status, _, data = _post(kernel_server.url, json.dumps(_scene([name])).encode())
    assert _error(status, data) == (
        f"observer.spice.kernels = {name!r} is not allowed; expected the name of a SPICE kernel (a regular file) "
        "inside the server's --data-dir folders, relative to them")


@pytest.mark.parametrize("kernels, body, expected", [
    (["broken.bsp"], "-999", "broken.bsp: SPICE("),          # not a kernel: CSPICE's error, one line
    (["craft.bsp"], "-555", "craft.bsp: SPICE(SPKINSUFFDATA)"),  # a body with no data
])
def test_a_bad_kernel_is_one_line_and_the_service_answers_on(kernel_server, tree, kernels, body, expected):
    status, _, data = _post(kernel_server.url, json.dumps(_scene(kernels, body)).encode())
    msg = _error(status, data)
    assert msg.startswith(expected) and str(tree) not in msg and os.path.realpath(tree) not in msg
    status, _, _ = _post(kernel_server.url, json.dumps(_scene(["craft.bsp"])).encode())
    assert status == 200


def test_a_planetary_spk_follows_the_same_rule(kernel_server, tree):
    """``ephemeris: {spk: NAME}``: outside the folders the generic 400; inside but without the
    planets (the craft's SPK) CSPICE's one line; the service answers on."""
    m = small_scene(size=64)
    m["outputs"] = ["truth"]
    status, _, data = _post(kernel_server.url, json.dumps({**m, "ephemeris": {"spk": "../secret/craft.bsp"}}).encode())
    assert _error(status, data) == (
        "ephemeris.spk = '../secret/craft.bsp' is not allowed; expected the name of a SPICE kernel (a regular file) "
        "inside the server's --data-dir folders, relative to them")
    status, _, data = _post(kernel_server.url, json.dumps({**m, "ephemeris": {"spk": "craft.bsp"}}).encode())
    msg = _error(status, data)
    assert msg.startswith("craft.bsp: SPICE(SPKINSUFFDATA)") and str(tree) not in msg
    status, _, _ = _post(kernel_server.url, json.dumps(m).encode())
    assert status == 200
