"""A request names files only inside the server's --data-dir folders, and learns nothing else.

Real files, symlinks, a FIFO, a link to /dev/zero, ``../`` and absolute paths against a real
server on loopback: every name the operator did not allow gets a 400 with one generic line (the
same for a missing file as for an existing one), the allowed names a 200 whose truth records the
name as given and the tables' digest, never a server path.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from .conftest import small_scene, start_server
from .test_bad_requests import _error, _post

CAP = 200_000   # --max-data-file-bytes of the test server


def _gaussian_image(n=17, sigma=2.0):
    y, x = np.mgrid[: n, : n] - (n - 1) / 2
    return np.exp(-(x * x + y * y) / (2 * sigma * sigma))


@pytest.fixture(scope="module")
def tree(tmp_path_factory):
    """``data/`` (allowed) and ``secret/`` (not) with files, links, a FIFO and a big file."""
    root = tmp_path_factory.mktemp("files")
    data, secret = root / "data", root / "secret"
    (data / "sub").mkdir(parents=True)
    secret.mkdir()
    np.save(data / "psf.npy", _gaussian_image())
    np.save(data / "sub" / "wide.npy", _gaussian_image(sigma=3.0))
    np.save(secret / "psf.npy", _gaussian_image())
    np.save(data / "big.npy", np.ones((200, 200)))            # 320 KB > CAP
    os.symlink(data / "psf.npy", data / "inside.npy")          # a link inside: allowed
    os.symlink(secret / "psf.npy", data / "outside.npy")       # a link out of the folder
    os.symlink("/dev/zero", data / "zero.fits")
    os.mkfifo(data / "fifo.npy")
    (data / "folder.npy").mkdir()
    return root


@pytest.fixture(scope="module")
def files_server(tree):
    s = start_server("--data-dir", str(tree / "data"), "--max-data-file-bytes", str(CAP))
    yield s
    s.stop()


def _scene(psf):
    m = small_scene(size=64)
    m["camera"]["psf"] = {"model": "tabulated", "oversampling": 1, **psf}
    m["outputs"] = ["truth"]
    return m


def _generic(key, name):
    return (f"{key} = {name!r} is not allowed; expected the name of a regular .npy or .fits file of at most {CAP} "
            "bytes inside the server's --data-dir folders, relative to them")


@pytest.mark.parametrize("name", ["psf.npy", "inside.npy", "sub/wide.npy", "sub/../psf.npy"])
def test_allowed_names_render_and_the_truth_keeps_the_name(files_server, tree, name):
    status, _, data = _post(files_server.url, json.dumps(_scene({"file": name})).encode())
    assert status == 200, data[:300]
    psf = json.loads(data)["camera"]["psf"]
    assert psf["file"] == name and len(psf["sha256"]) == 64
    assert str(tree) not in data.decode() and os.path.realpath(tree) not in data.decode()


def test_a_field_grid_of_allowed_names(files_server):
    field = [{"x_px": x, "y_px": y, "file": "psf.npy"} for x in (0, 63) for y in (0, 63)]
    status, _, data = _post(files_server.url, json.dumps(_scene({"field": field})).encode())
    assert status == 200, data[:300]
    assert [p["file"] for p in json.loads(data)["camera"]["psf"]["field"]] == ["psf.npy"] * 4


def _refused_names(tree):
    return ["missing.npy", "outside.npy", "zero.fits", "fifo.npy", "folder.npy", "big.npy",
            "../secret/psf.npy", "sub/../../secret/psf.npy", str(tree / "data" / "psf.npy"),
            str(tree / "secret" / "psf.npy"), "/dev/zero.npy"]


def test_every_other_name_gets_the_same_generic_400(files_server, tree):
    for name in _refused_names(tree):
        status, _, data = _post(files_server.url, json.dumps(_scene({"file": name})).encode())
        assert _error(status, data) == _generic("camera.psf.file", name), name


def test_a_field_file_outside_is_refused_by_its_key(files_server):
    field = [{"x_px": x, "y_px": 0, "file": f} for x, f in ((0, "psf.npy"), (63, "../secret/psf.npy"))]
    status, _, data = _post(files_server.url, json.dumps(_scene({"field": field})).encode())
    assert _error(status, data) == _generic("camera.psf.field[1].file", "../secret/psf.npy")


def test_a_wrong_digest_does_not_reveal_a_file_outside(files_server):
    status, _, data = _post(files_server.url, json.dumps(_scene({"file": "outside.npy", "sha256": "0" * 64})).encode())
    assert _error(status, data) == _generic("camera.psf.file", "outside.npy")


def test_without_data_dir_a_request_names_no_file(server, tree):
    for name in ("psf.npy", str(tree / "data" / "psf.npy")):
        status, _, data = _post(server.url, json.dumps(_scene({"file": name})).encode())
        msg = _error(status, data)
        assert msg.startswith("camera.psf.file = ") and "this server reads no files" in msg
        assert str(tree) not in msg.replace(repr(name), "")


def test_the_server_still_answers_after_the_fifo_and_dev_zero(files_server):
    status, _, _ = _post(files_server.url, json.dumps(_scene({"file": "psf.npy"})).encode())
    assert status == 200
