"""What fixes the bits is in the manifest, and a resume that would change the bits is refused.

The manifest records the render options (``dataclasses.asdict(RenderOptions)``) and the backends
that ran, resolved (``sensor``: llvm | numpy; ``mitsuba_variant``). A resume with other options or
on another backend is refused with one line naming the option, the old and the new value; a resume
with the same ones finishes byte-identical to the 1-worker reference (the same code with the
same seeds: a determinism demand).
"""

from __future__ import annotations

import ast
import dataclasses
import json
from pathlib import Path

import pytest

import skynav.datasets as D
from skynav.datasets import generate
from skynav.renderer.render import RenderOptions

from .conftest import small_recipe, tree_sha256


def _partial(tmp_path, **kw) -> Path:
    """The first 2 of 4 frames of the small recipe (an interrupted run)."""
    out = tmp_path / "ds"
    s = generate(small_recipe(frames=4), out, workers=1, progress=False, max_frames=2, **kw)
    assert s.frames_rendered == 2
    assert json.loads((out / "manifest.json").read_text())["complete"] is False
    return out


def test_manifest_records_render_options_and_resolved_backends(reference_dataset):
    from skynav.renderer import jit_backend

    out, _, _ = reference_dataset
    m = json.loads((out / "manifest.json").read_text())
    assert m["render_options"] == dataclasses.asdict(RenderOptions())
    # "auto" resolved as the renderer resolves it, independently asked here
    assert m["backends"]["sensor"] == jit_backend.auto_sensor_backend()
    assert m["backends"]["mitsuba_variant"] == jit_backend.select_mitsuba_variant()[0]
    assert m["backends"]["mitsuba_variant"] in ("cuda_ad_spectral", "llvm_ad_spectral", "scalar_spectral")


def test_resume_with_other_render_options_is_refused_in_one_line(tmp_path):
    out = _partial(tmp_path)
    before = tree_sha256(out)
    with pytest.raises(D.DatasetMismatchError) as err:
        generate(small_recipe(frames=4), out, workers=1, progress=False,
                 render_options=RenderOptions(mitsuba_spp=32))
    msg = str(err.value)
    assert "\n" not in msg
    assert "render option mitsuba_spp = 16, this run has 32" in msg
    assert tree_sha256(out) == before  # nothing written


def test_resume_on_another_sensor_backend_is_refused(tmp_path):
    out = _partial(tmp_path)
    m = json.loads((out / "manifest.json").read_text())
    ran = m["backends"]["sensor"]
    other = "numpy" if ran == "llvm" else "llvm"
    m["backends"]["sensor"] = other  # as if the first session ran on a machine with the other backend
    (out / "manifest.json").write_text(json.dumps(m, indent=2) + "\n")
    with pytest.raises(D.DatasetMismatchError, match=f"backend sensor = '{other}', this run has '{ran}'"):
        generate(small_recipe(frames=4), out, workers=1, progress=False)


def test_an_unrecorded_frame_made_on_another_backend_is_rendered_again(reference_dataset, tmp_path):
    _, _, ref = reference_dataset
    out = _partial(tmp_path)
    m = json.loads((out / "manifest.json").read_text())
    # frame 1 finished as the run stopped: files on disk, not yet in the manifest; its truth says
    # the other sensor backend ran (a worker without LLVM, say)
    m["files"] = {k: v for k, v in m["files"].items() if not k.startswith("frames/000001.")}
    (out / "manifest.json").write_text(json.dumps(m, indent=2) + "\n")
    truth_path = out / "frames" / "000001.json"
    truth = json.loads(truth_path.read_text())
    truth["render"]["backend_used"] = "numpy" if m["backends"]["sensor"] == "llvm" else "llvm"
    truth_path.write_text(json.dumps(truth))
    s = generate(small_recipe(frames=4), out, workers=1, progress=False)
    assert s.frames_reused == 1 and s.frames_rendered == 3
    got = tree_sha256(out)
    assert all(got[k] == ref[k] for k in got if k.startswith("frames/"))


def test_a_worker_on_another_backend_is_refused():
    from skynav.datasets.execute import FrameResult, check_backends

    res = FrameResult(frame=3, files={}, index_row={}, draws=None, timings_s={},
                      backends={"sensor": "numpy", "mitsuba_variant": None})
    check_backends(res, {"sensor": "numpy", "mitsuba_variant": "llvm_ad_spectral"})  # no body traced: fine
    with pytest.raises(D.DatasetMismatchError, match="frame 3 ran with sensor 'numpy' but this dataset records 'llvm'"):
        check_backends(res, {"sensor": "llvm", "mitsuba_variant": "llvm_ad_spectral"})


def test_resume_with_the_same_options_is_byte_identical(reference_dataset, tmp_path):
    """The same code, the same seeds, the same options: the same files."""
    _, _, ref = reference_dataset
    out = _partial(tmp_path)
    s = generate(small_recipe(frames=4), out, workers=1, progress=False, render_options=RenderOptions())
    assert s.frames_reused == 2 and s.frames_rendered == 2
    got = tree_sha256(out)
    frames = sorted(k for k in got if k.startswith("frames/"))
    assert len(frames) == 16 and all(got[k] == ref[k] for k in frames)  # 4 x (png, exr, json, sha256 record): = the 50-frame reference's first 4
    assert D.verify(out).ok


def test_explicit_backend_is_recorded(tmp_path):
    out = tmp_path / "ds"
    generate(small_recipe(frames=1), out, workers=1, progress=False,
             render_options=RenderOptions(backend="numpy", resolved=False))
    m = json.loads((out / "manifest.json").read_text())
    assert m["render_options"]["backend"] == "numpy" and m["render_options"]["resolved"] is False
    assert m["backends"] == {"sensor": "numpy", "mitsuba_variant": None}
    # regenerate_frame uses the recorded options: same bytes
    res = D.regenerate_frame(out, 0, tmp_path / "again")
    assert all(res.files[k] == tree_sha256(out)[k] for k in res.files)


def _imports(path: Path) -> set:
    """Modules a source file imports anywhere (module level or inside functions), relative names as '.x'."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            out.add("." * node.level + (node.module or ""))
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return out


def test_samplers_and_sequence_do_not_import_each_other():
    import skynav.datasets.plan as plan
    import skynav.datasets.samplers as samplers
    import skynav.datasets.sequence as sequence

    seq, smp, pln = (_imports(Path(m.__file__)) for m in (sequence, samplers, plan))
    assert not {".samplers", "skynav.datasets.samplers"} & seq
    assert ".plan" in seq and ".plan" in smp
    assert not {".samplers", ".sequence", ".runner", ".execute", ".finalise"} & pln
