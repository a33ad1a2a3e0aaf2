"""Property-based fuzz of scene and recipe mappings.

Each example mutates a good scene file (one to three keys replaced by a value of another type or
an extreme number, deleted, or added) and runs ``skynav render`` on it in this process. Allowed
outcomes: exit 0 with ground truth that is finite and self-consistent (orthonormal attitude,
unit quaternion matching it, ``K`` matching the camera, bodies flagged ``in_fov`` inside the
frame), or exit 2 with one ``skynav: error:`` line. Never a traceback, never more than
``CASE_LIMIT_S`` per case (a SIGALRM turns a hang into a failure). Rendered frames are capped at
512 x 512 px (larger values are checked for refusal by the catalogue; a legitimate 10000 x 10000
frame takes minutes, which is not a hang).

The CI run draws ``FUZZ_EXAMPLES`` scenes and 40 recipes; ``-m slow`` draws 1000 scenes
(``-s`` prints its figures).
"""

from __future__ import annotations

import copy
import json
import math
import signal
import time
from collections import Counter

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skynav.__main__ import main

CASE_LIMIT_S = 60
FUZZ_EXAMPLES = 60

BASE = {
    "epoch": "2027-02-01T00:00:00",
    "observer": {"position_km": [-128731399.4, 113269566.7, 51647643.2], "velocity_km_s": [-19.9093, -18.773, -8.1391]},
    "attitude": {"point_at": "mars", "twist_deg": 0.0, "angular_velocity_deg_s": [0.0, 0.0, 0.0]},
    "camera": {"preset": "paper", "width": 96, "height": 80, "fov_deg": 20.0, "exposure_s": 0.4, "f_number": 2.2,
               "distortion": {"k1": 0.0}, "sensor": {"bit_depth": 12, "full_well_e": 20000.0, "read_noise_e": 8.0}},
    "visibility": {"limiting_v_mag": 7.0, "sun_exclusion_deg": 20.0},
    "render": {"catalog_limiting_v_mag": 7.0, "cosmic_rays_per_frame": 1.0, "resolved_threshold_px": 2.0, "seed": 3},
}


def _paths(d, prefix=()):
    for k, v in d.items():
        yield prefix + (k,)
        if isinstance(v, dict):
            yield from _paths(v, prefix + (k,))


PATHS = list(_paths(BASE))

numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=-1e6, max_value=1e6),
    st.integers(min_value=-10**12, max_value=10**12),
    st.sampled_from([0, -1, 1, 1e-30, 1e30, 1e300, -1e300, 2**63, 0.5, 179.999, 1e7, 3e5]),
)
scalars = st.one_of(numbers, st.booleans(), st.none(), st.text(max_size=12),
                    st.sampled_from(["sun", "mars", "auto", "paper", "earth", "2e-1", "2027-01-01", "1e30"]))
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                       st.dictionaries(st.text(max_size=8), inner, max_size=3)),
                      max_leaves=6)
factors = st.one_of(st.floats(min_value=-3.0, max_value=3.0), st.sampled_from([0.0, -1.0, 1e-6, 1e6, 1e30]))
mutation = st.tuples(st.sampled_from(PATHS), st.sampled_from(["replace", "delete", "add", "scale", "scale", "scale"]),
                     st.one_of(values, factors), st.text(min_size=1, max_size=8))


def apply(base: dict, muts) -> dict:
    d = copy.deepcopy(base)
    for path, how, value, new_key in muts:
        node = d
        for k in path[:-1]:
            if not isinstance(node, dict) or not isinstance(node.get(k), dict):
                break
            node = node[k]
        else:
            if how == "replace":
                node[path[-1]] = value
            elif how == "scale":  # a plausible neighbour: numbers times 10**f (or times f when f is extreme)
                f = value if isinstance(value, float) else 1.0
                m = 10.0 ** f if abs(f) <= 3 else f

                def scaled(v):
                    if isinstance(v, bool) or not isinstance(v, (int, float)):
                        return v
                    x = v * m
                    return int(round(x)) if isinstance(v, int) and math.isfinite(x) and abs(x) < 2**62 else x

                old = node.get(path[-1])
                node[path[-1]] = [scaled(v) for v in old] if isinstance(old, list) else scaled(old)
            elif how == "delete":
                node.pop(path[-1], None)
            else:
                node[new_key] = value
    cam = d.get("camera")
    if isinstance(cam, dict):  # frames rendered here stay small (see the module docstring)
        for k in ("width", "height"):
            v = cam.get(k)
            if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and abs(v) > 512:
                cam[k] = 512
    return d


class _Hang(Exception):
    pass


def _alarm(signum, frame):
    raise _Hang()


def check_truth(truth: dict) -> None:
    """Finite and self-consistent ground truth (raises AssertionError)."""
    json.dumps(truth, allow_nan=False)  # every number finite
    R = np.asarray(truth["attitude"]["R_cam_icrs"], dtype=float)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-9) and np.isclose(np.linalg.det(R), 1.0, atol=1e-9)
    q = np.asarray(truth["attitude"]["q_cam_icrs"], dtype=float)
    assert np.isclose(np.linalg.norm(q), 1.0, atol=1e-9)
    q0, qv = q[0], q[1:]
    A = (q0**2 - qv @ qv) * np.eye(3) + 2 * np.outer(qv, qv) - 2 * q0 * np.array(
        [[0, -qv[2], qv[1]], [qv[2], 0, -qv[0]], [-qv[1], qv[0], 0]])
    assert np.allclose(A, R, atol=1e-8)  # docs/conventions.md: Andreis et al. (2023a), Eq. 14
    cam = truth["camera"]
    K = np.asarray(cam["K"], dtype=float)
    w, h = cam["width"], cam["height"]
    assert K[0, 0] > 0 and K[1, 1] > 0 and np.allclose(K[2], [0, 0, 1])
    f_px = cam["focal_length_mm"] * 1e3 / cam["pixel_pitch_um"]
    assert math.isclose(K[0, 0], f_px, rel_tol=1e-9)
    for b in truth["bodies"]:
        if b["in_fov"]:
            x, y = b["xy"]
            assert -0.5 - 1e-6 <= x <= w - 0.5 + 1e-6 and -0.5 - 1e-6 <= y <= h - 0.5 + 1e-6, (b["name"], b["xy"])
        assert b["distance_km"] > 0 and b["light_time_s"] > 0
    for s in truth["stars"]:
        assert np.isclose(np.linalg.norm(s["u_icrs"]), 1.0, atol=1e-9) and s["electrons"] >= 0


def run_case(mapping: dict, tmp, capsys, stats: Counter, kind: str = "scene") -> None:
    f = tmp / "case.yaml"
    f.write_text(yaml.safe_dump(mapping, allow_unicode=True))
    out = tmp / "out"
    if kind == "scene":
        argv = ["render", str(f), "-o", str(out), "--name", "f", "--no-noise"]
    else:
        argv = ["dataset", "generate", str(f), "-o", str(tmp / f"ds{stats.total()}"), "--workers", "1", "-q"]
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(CASE_LIMIT_S)
    t0 = time.perf_counter()
    try:
        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code
        except _Hang:
            pytest.fail(f"hang: more than {CASE_LIMIT_S} s on {mapping}")
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    stats["seconds"] += time.perf_counter() - t0
    _, err = capsys.readouterr()
    assert "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("skynav: warning:")]
    lines = [ln for ln in lines if not ln.startswith("skynav: Mitsuba variant")]  # the one-time backend note
    if code == 0:
        stats["ok"] += 1
        if kind == "scene":
            check_truth(json.loads((out / "f.json").read_text()))
    else:
        assert code == 2 and len(lines) == 1 and lines[0].startswith("skynav: error:"), (code, err, mapping)
        stats["refused"] += 1


def _fuzz(n_examples: int, stats: Counter, tmp_path_factory, capsys):
    @settings(max_examples=n_examples, deadline=None, database=None, derandomize=True,
              suppress_health_check=list(HealthCheck))
    @given(st.lists(mutation, min_size=1, max_size=3))
    def inner(muts):
        run_case(apply(BASE, muts), tmp_path_factory.mktemp("fz"), capsys, stats)

    inner()


def test_fuzzed_scene_files(tmp_path_factory, capsys):
    stats = Counter()
    _fuzz(FUZZ_EXAMPLES, stats, tmp_path_factory, capsys)
    assert stats["ok"] + stats["refused"] >= FUZZ_EXAMPLES


@pytest.mark.slow
def test_fuzzed_scene_files_long(tmp_path_factory, capsys):
    stats = Counter()
    t0 = time.perf_counter()
    _fuzz(1000, stats, tmp_path_factory, capsys)
    with capsys.disabled():
        print(f"\nfuzz (long): {stats['ok'] + stats['refused']} scene files, {stats['ok']} rendered and checked, "
              f"{stats['refused']} refused in one line, 0 tracebacks, 0 hangs; {time.perf_counter() - t0:.0f} s "
              f"(max {CASE_LIMIT_S} s per case)")
    assert stats["ok"] + stats["refused"] >= 1000


RECIPE_BASE = {"kind": "scenes", "seed": 1, "camera": {"preset": "paper", "width": 48, "height": 48},
               "catalog_limiting_v_mag": 6.0, "formats": ["png", "json"],
               "scenes": [{"epoch": "2027-03-15T00:00:00",
                           "observer": {"position_km": [120000000.0, -90000000.0, -39000000.0],
                                        "velocity_km_s": [18.0, 21.0, 9.0]},
                           "attitude": {"point_at": "mars"}}]}
RECIPE_PATHS = [p for p in _paths(RECIPE_BASE)] + [("scenes",)]


@settings(max_examples=40, deadline=None, database=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(st.lists(st.tuples(st.sampled_from(RECIPE_PATHS), st.sampled_from(["replace", "delete", "add"]), values,
                          st.text(min_size=1, max_size=8)), min_size=1, max_size=2))
def test_fuzzed_recipes(tmp_path_factory, capsys, muts):
    mapping = apply(RECIPE_BASE, muts)
    if isinstance(mapping.get("frames"), (int, float)) and not isinstance(mapping.get("frames"), bool):
        mapping["frames"] = min(mapping["frames"], 3) if math.isfinite(mapping["frames"]) else mapping["frames"]
    run_case(mapping, tmp_path_factory.mktemp("fr"), capsys, Counter(), kind="recipe")
