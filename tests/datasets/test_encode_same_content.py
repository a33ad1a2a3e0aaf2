"""The encoders and the sampler changed bytes and speed, not content.

Reference: ``data/main_a259a83/`` was written by skynav's main branch at commit a259a83, before
the encoders changed (EXR ZIP -> RLE, PNG by Pillow -> filter None + zlib RLE, truth JSON by the
standard library -> orjson lines) and before the Monte Carlo keep-filter tested its draws in
batches:

- ``mc8/`` and ``mc12/``: two frames each of the Monte Carlo preset on a 48 x 40 camera of 8 and
  12 bits (``png``, ``exr``, ``json``: 12 bits exercise the scaled 16-bit PNG with ``sBIT``);
- ``montecarlo_plan_200.json``: the first 200 frame requests of the Monte Carlo preset (epoch,
  state, attitude, metadata with the number of draws, and the next integer the frame's stream
  gives after the sampler, i.e. where the renderer starts).

What is compared, and why it is honest: the renderer is being changed by other work (PSF), so the
images are not re-rendered here; main's decoded content (pixels, truth values) is written by
today's writers and decoded again, and must come back identical, bit for bit (the writers are
lossless; same values in, same values out). The plan is the same code path before and after for
the same seeds: its draws, decisions and the random stream are compared exactly, its floats within
1e-13 (the reference was written on an AVX-512 CPU; numpy's baseline trigonometry differs in
the last bit, which `.ci/run`'s second pass exercises).
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

REF = Path(__file__).parent / "data" / "main_a259a83"


def _decoded(folder: Path, stem: str) -> dict:
    from skynav.datasets.frame_files import read_exr, read_png, read_png_layout
    from skynav.datasets.truth_schema import read_truth_json

    exr = read_exr(folder / f"{stem}.exr")
    return {"dn": read_png(folder / f"{stem}.png"), "png_layout": read_png_layout(folder / f"{stem}.png"),
            "electrons": exr["electrons"], "irradiance_w_m2": exr["irradiance_w_m2"],
            "truth": read_truth_json(folder / f"{stem}.json")}


def _round_trip_exact(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a.view(np.uint8), b.view(np.uint8))


@pytest.mark.parametrize("bits", [8, 12])
@pytest.mark.parametrize("stem", ["000000", "000001"])
def test_writers_give_back_mains_decoded_content(tmp_path, bits, stem):
    from skynav.datasets.frame_files import write_frame

    ref = _decoded(REF / f"mc{bits}", stem)
    assert ref["dn"].dtype == (np.uint8 if bits <= 8 else np.uint16) and ref["dn"].max() > 0
    assert np.count_nonzero(ref["electrons"]) > 0
    frame = SimpleNamespace(dn=ref["dn"], electrons=ref["electrons"], irradiance_w_m2=ref["irradiance_w_m2"],
                            truth=ref["truth"])
    write_frame(frame, tmp_path, stem, formats=("png", "exr", "json"))
    new = _decoded(tmp_path, stem)
    for key in ("dn", "electrons", "irradiance_w_m2"):
        assert _round_trip_exact(new[key], ref[key]), key
    assert new["png_layout"] == ref["png_layout"] == {"png_scaling": "sbit", "significant_bits": bits}
    assert new["truth"] == ref["truth"]  # floats read back bit-exact from both files
    # the bytes did change (new encoders), so this is not comparing a file with itself
    for ext in ("png", "exr", "json"):
        assert (tmp_path / f"{stem}.{ext}").read_bytes() != (REF / f"mc{bits}" / f"{stem}.{ext}").read_bytes()


def test_montecarlo_plan_of_200_frames_is_mains():
    from skynav.datasets import preset_recipe
    from skynav.datasets.recipe_checks import validate_recipe
    from skynav.datasets.samplers import frame_seed, make_plan

    ref = json.loads((REF / "montecarlo_plan_200.json").read_text())
    rec = validate_recipe(dict(preset_recipe("montecarlo"), frames=200))
    plan = make_plan(rec)
    for k, want in enumerate(ref):
        rng = np.random.default_rng(frame_seed(rec["seed"], k))
        r = plan.frame_request(k, rng)
        # the same draws and the same keep decisions: the frame's metadata (draw counts, kept
        # pose) and the stream's next integer exactly; the poses' floats within 1e-13 relative
        # (1e-15 absolute for rotation entries): they pass through numpy's trigonometry, whose
        # SIMD and baseline loops differ in the last bit (the reference was written on AVX-512)
        assert r.meta == want["meta"] and int(rng.integers(0, 2**62)) == want["next"], f"frame {k}"
        for key, got in (("t", [r.epoch_tdb_s]), ("r", r.position_km), ("v", r.velocity_km_s),
                         ("R", np.asarray(r.R_cam_icrs).ravel())):
            np.testing.assert_allclose(np.asarray(got, float), np.atleast_1d(want[key]), rtol=1e-13, atol=1e-15,
                                       err_msg=f"frame {k} {key}")
    assert sum(w["meta"]["draws"] for w in ref) > 2 * len(ref)  # the keep-filter rejected draws
