"""Every numeric field of a request with an integer of 400 digits gets a 400 naming the field.

The fields are found by walking a request that spells out every camera, render and attitude key
(the paper camera's mapping, :data:`skynav.scenes.config.RENDER_KEYS`), not listed by hand.
"""

from __future__ import annotations

import copy
import json

from .test_bad_requests import _error, _post


def full_request() -> dict:
    from skynav.scenes.camera import paper_camera
    from skynav.scenes.config import RENDER_KEYS
    from skynav.scenes.presets import preset_mapping

    m = preset_mapping("default")
    cam = paper_camera().to_dict()
    for k in ("K", "cx", "cy"):
        cam.pop(k)
    cam.update(width=64, height=64)
    m["camera"] = cam
    m["render"] = {k: default for k, (default, _) in RENDER_KEYS.items()}
    m["attitude"]["twist_deg"] = 0.0
    m["outputs"] = ["truth"]
    return m


def numeric_fields(node, path=""):
    """``(dotted key, setter path)`` of every number in ``node`` (the first of a long table)."""
    if isinstance(node, bool):
        return
    if isinstance(node, (int, float)):
        yield path
    elif isinstance(node, dict):
        for k, v in node.items():
            yield from numeric_fields(v, f"{path}.{k}" if path else k)
    elif isinstance(node, list):
        for i, v in enumerate(node if len(node) <= 9 else node[:1]):
            yield from numeric_fields(v, f"{path}[{i}]")


def _set(m, dotted, value):
    import re

    keys = [int(k) if k.isdigit() else k for k in re.findall(r"[^.\[\]]+", dotted)]
    for k in keys[:-1]:
        m = m[k]
    m[keys[-1]] = value


def test_the_full_request_renders(server):
    status, _, data = _post(server.url, json.dumps(full_request()).encode())
    assert status == 200, data[:300]


def test_a_400_digit_integer_in_every_numeric_field_is_a_400_naming_it(server):
    base = full_request()
    fields = list(numeric_fields(base))
    assert len(fields) >= 23
    for field in fields:
        for sign in (1, -1):
            m = copy.deepcopy(base)
            _set(m, field, sign * 10**399)
            status, _, data = _post(server.url, json.dumps(m).encode())
            msg = _error(status, data)
            assert msg.startswith(f"{field} = an integer of 400 digits is not allowed"), (field, msg)


def test_a_response_band_beyond_the_far_infrared_is_a_400(server):
    for i, value in ((0, -1e308), (-1, 1e308)):
        m = full_request()
        m["camera"]["response"]["wavelengths_nm"][i] = value
        status, _, data = _post(server.url, json.dumps(m).encode())
        assert _error(status, data).startswith("camera.response.wavelengths_nm = ")
