"""A request's cost is bounded: the cost model refuses what is above the budget, naming the key;
behind it each worker's address-space cap and the request deadline answer 503 and replace the
worker; meanwhile another client keeps getting its frames.

The hostile requests and the measurements are those of ``benchmarks/service_hostile_bench.py``
(a real ``skynav serve --workers 2`` on loopback, each worker under its cap, another client
asking for 64 x 64 frames throughout): run here, its lines are checked; nothing is timed (the
other client's round trips are printed by the script, and docs/performance.md has them).
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from skynav.infra.errors import ConfigValueError

from .conftest import small_scene

ROOT = Path(__file__).resolve().parents[2]
LINE = re.compile(r"HOSTILE (.+?): (\d{3}) in [0-9.]+ s; worker peak RSS (\d+) MiB \(cap ([0-9.]+) GiB\); .*?; (.*)")

#: The key each hostile request is refused by (the budget on).
KEYS = {"gaussian sigma_px 1000": "camera.psf.sigma_px", "defocus_sigma_px 1000": "camera.defocus_sigma_px",
        "airy max_half_px 64 at 256^2": "camera.psf.max_half_px",
        "streak 50 s at 1 deg/s, 1024^2": "attitude.angular_velocity_deg_s",
        "8 MB PSF at 900 grid points": "camera.psf.field[", "mitsuba_spp 1024 on a 1024^2 Earth": "render.mitsuba_spp",
        "mitsuba_spp 4096 at 256^2": "render.mitsuba_spp", "mitsuba_spp 65536 at 256^2": "render.mitsuba_spp"}


def _bench(*args) -> tuple:
    """``({name: (status, peak MiB, cap GiB, line)}, the OTHER CLIENT line)`` of one run of the script."""
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "service_hostile_bench.py"), *args],
                          capture_output=True, text=True, cwd=ROOT, timeout=1500)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = {m.group(1): (int(m.group(2)), int(m.group(3)), float(m.group(4)), m.group(5))
            for m in map(LINE.match, proc.stdout.splitlines()) if m}
    other = next((line for line in proc.stdout.splitlines() if line.startswith("OTHER CLIENT:")), "")
    assert rows and other, proc.stdout
    return rows, other


def _scene_and_options(mapping):
    from skynav.renderer.render import RenderOptions
    from skynav.scenes.config import scene_spec_from_mapping
    from skynav.scenes.scene import build_from_spec

    spec = scene_spec_from_mapping(mapping)
    return build_from_spec(spec), RenderOptions(noise=True, backend="auto", mitsuba_spp=spec.mitsuba_spp)


def test_the_default_frames_are_within_the_default_budget():
    from skynav.service.budget import Budget, check_budget

    for name, size in (("default", 1024), ("default", 64), ("earth_departure", 1024)):
        m = small_scene(name, size=size)
        parts = check_budget(*_scene_and_options(m), Budget(), m)
        assert {p.key for p in parts} >= {"camera.width x camera.height"}


@pytest.mark.parametrize("camera,key", [({"psf": {"model": "gaussian", "sigma_px": 1000}}, "camera.psf.sigma_px"),
                                        ({"defocus_sigma_px": 1000}, "camera.defocus_sigma_px")])
def test_a_wide_gaussian_is_refused_naming_its_key_and_the_limit(camera, key):
    from skynav.service.budget import Budget, check_budget

    m = small_scene(size=64, camera=camera)
    with pytest.raises(ConfigValueError) as e:
        check_budget(*_scene_and_options(m), Budget(), m)
    assert str(e.value).startswith(f"{key} = 1000 is not allowed; expected a request within this server's memory "
                                   "budget: about ") and "at most 1.00 GiB (skynav serve --max-request-memory)" in str(e.value)


def test_a_mitsuba_wavefront_past_2_32_samples_is_refused_whatever_the_budget():
    from skynav.service.budget import Budget, check_budget

    m = small_scene("earth_departure", size=256, render={"mitsuba_spp": 65536})
    m["observer"]["position_km"] = [x * 0.1 for x in m["observer"]["position_km"]]   # a 300 px Earth
    with pytest.raises(ConfigValueError) as e:
        check_budget(*_scene_and_options(m), Budget(max_bytes=1e15, max_seconds=1e9), m)
    assert re.match(r"render\.mitsuba_spp = 65536 is not allowed; expected at most \d+ for earth's", str(e.value))


def test_hostile_requests_are_refused_before_rendering_and_others_keep_their_frames():
    rows, other = _bench()
    assert set(rows) == set(KEYS)
    for name, (status, peak_mib, cap_gib, line) in rows.items():
        assert status == 400 and line.startswith(KEYS[name]), (name, status, line)
        assert peak_mib < cap_gib * 1024, (name, peak_mib)
    assert "all 200: True, identical bytes: True" in other, other


def test_behind_the_estimate_the_memory_cap_and_the_deadline_answer_503_and_replace_the_worker():
    # the cost model off: a 1.25 GiB cap (a warm worker reserves about 0.95 GiB) and a 3 s deadline
    rows, other = _bench("--no-budget", "-k", "gaussian|4096", "--worker-memory", str(1280 << 20),
                         "--request-deadline", "3")
    assert rows["gaussian sigma_px 1000"][0] == 503
    assert rows["gaussian sigma_px 1000"][3].startswith("the render reached the worker's memory cap")
    assert rows["mitsuba_spp 4096 at 256^2"][0] == 503
    assert rows["mitsuba_spp 4096 at 256^2"][3].startswith("the render went past the server's deadline of 3 s")
    assert all(peak < cap * 1024 for _, peak, cap, _ in rows.values()), rows
    assert "all 200: True, identical bytes: True" in other, other


@pytest.mark.slow
def test_without_the_cost_model_no_hostile_request_passes_the_cap_or_gets_a_500():
    rows, other = _bench("--no-budget", "--request-deadline", "30")
    assert set(rows) == set(KEYS)
    for name, (status, peak_mib, cap_gib, line) in rows.items():
        assert status in (200, 400, 503) and peak_mib < cap_gib * 1024, (name, status, peak_mib, line)
    assert "all 200: True, identical bytes: True" in other, other


def test_the_cost_bench_prints_each_estimate_beside_what_was_measured():
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "request_cost_bench.py"), "-k", "gaussian sigma 20"],
                          capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    row = re.search(r"gaussian sigma 20 +([0-9.]+) +([0-9.]+) +([0-9.]+) +([0-9.]+) +([0-9.]+) +([0-9.]+) +([0-9.]+)",
                    proc.stdout)
    assert row and float(row.group(1)) > 0 and "WORST memory ratio" in proc.stdout, proc.stdout
