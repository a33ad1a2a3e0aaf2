"""Extreme floats in every numeric field of a render request: a 200 or a 400 naming the field, never a 500.

The class of bug: a tiny positive value (1e-308, the subnormal 5e-324) passes a ``> 0`` check but
overflows what is derived from it (a focal length in pixels, an aperture, a Planck spectrum), and a
huge one (1e308) overflows a product. The fields are found by walking requests that spell out every
key of the schema (the paper camera's mapping, the render keys, each PSF model, each attitude mode:
:func:`requests`), not listed by hand. JSON has no NaN nor infinity: a body that holds them is
refused as a whole (:func:`test_nan_and_infinity_are_not_json`).
"""

from __future__ import annotations

import copy
import json
import subprocess
import sys

import pytest

from .test_bad_requests import _post
from .test_numeric_fields import _set, full_request, numeric_fields

EXTREMES = (1e-308, 5e-324, 1e308, -0.0, -1e-308, -1e308)


def requests() -> list:
    """Requests that together hold every numeric key of the schema."""
    base = full_request()
    out = [base]
    for psf in ({"model": "airy", "obscuration": 0.3, "wavelength_nm": 600.0, "max_half_px": 8},
                {"model": "optical", "obscuration": 0.3, "wavelength_nm": 600.0, "zernike_waves": {"4": 0.1},
                 "max_half_px": 8}):
        m = copy.deepcopy(base)
        m["camera"]["psf"] = psf
        m["camera"].pop("defocus_sigma_px", None)
        out.append(m)
    m = copy.deepcopy(base)
    for k in ("focal_length_mm",):
        m["camera"].pop(k)
    m["camera"].update(fov_deg=2.0, cx=31.5, cy=31.5, pixel_pitch_y_um=m["camera"]["pixel_pitch_um"])
    m["attitude"] = {"ra_deg": 10.0, "dec_deg": 20.0, "twist_deg": 5.0, "angular_velocity_deg_s": [0.01, 0.02, 0.03]}
    out.append(m)
    m = copy.deepcopy(base)
    m["attitude"] = {"q_cam_icrs": [1.0, 0.0, 0.0, 0.0]}
    out.append(m)
    return out


def cases() -> list:
    """``(request index, dotted field)`` of every numeric field, each once."""
    seen, out = set(), []
    for i, m in enumerate(requests()):
        for field in numeric_fields(m):
            if field not in seen:
                seen.add(field)
                out.append((i, field))
    return out


def _check(url, i: int, field: str, value: float) -> None:
    m = copy.deepcopy(requests()[i])
    _set(m, field, value)
    status, _, data = _post(url, json.dumps(m).encode())
    assert status in (200, 400), (field, value, status, data[:300])
    if status == 400:
        msg = json.loads(data)["error"]
        assert "\n" not in msg and msg.split(".")[0].split(" ")[0] == field.split(".")[0].split("[")[0], (field, value, msg)


#: The fields that gave 500s before their validation had physical lower bounds, and a few others.
SAMPLE = ("camera.focal_length_mm", "camera.pixel_pitch_um", "camera.f_number", "camera.response.wavelengths_nm[0]",
          "camera.exposure_s", "camera.psf.wavelength_nm")


def test_every_numeric_field_is_covered():
    fields = [f for _, f in cases()]
    assert len(fields) >= 50 and set(SAMPLE) <= set(fields)
    assert {"attitude.q_cam_icrs[0]", "camera.fov_deg", "camera.psf.obscuration", "attitude.ra_deg"} <= set(fields)


@pytest.mark.parametrize("value", (1e-308, 5e-324, 1e308))
def test_a_sample_of_fields_with_extreme_floats_is_a_200_or_a_400(server, value):
    for i, field in cases():
        if field in SAMPLE:
            _check(server.url, i, field, value)


@pytest.mark.slow
def test_every_numeric_field_with_extreme_floats_is_a_200_or_a_400(server):
    for i, field in cases():
        for value in EXTREMES:
            _check(server.url, i, field, value)


def test_nan_and_infinity_are_not_json(server):
    body = json.dumps(full_request()).replace('"exposure_s": ', '"exposure_s": NaN, "x": ', 1).encode()
    for token in (b"NaN", b"Infinity", b"-Infinity"):
        status, _, data = _post(server.url, body.replace(b"NaN", token))
        assert status == 400 and json.loads(data)["error"].startswith("request body: not a JSON object"), data


@pytest.mark.parametrize("key,value", [("camera.focal_length_mm", "1e-308"), ("camera.f_number", "5e-324"),
                                       ("camera.pixel_pitch_um", "1e-308")])
def test_the_command_line_refuses_a_tiny_length_in_one_line(tmp_path, key, value):
    r = subprocess.run([sys.executable, "-m", "skynav", "render", "default", "--set", f"{key}={value}", "-o",
                        str(tmp_path / "f.png")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and not list(tmp_path.iterdir())
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"skynav: error: {key} = ") and "Traceback" not in r.stderr, r.stderr
