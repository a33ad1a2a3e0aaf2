"""skynav.datasets.stream: a recipe's frames in batches are the dataset's frames of the same
(seed, index), whatever the batch size or the shard; the labels are the truth's; the adapters
exchange the arrays through DLPack without a copy."""

from __future__ import annotations

import numpy as np
import pytest

import skynav.datasets as D
from skynav.datasets.errors import DatasetError
from skynav.datasets.labels import LABELS
from skynav.renderer import jit_backend

from .conftest import small_recipe


def tiny_recipe(frames: int = 5) -> dict:
    r = small_recipe(frames)
    r["camera"] = {"preset": "paper", "width": 64, "height": 64, "fov_deg": 20.0}
    r["render"] = {"cosmic_rays_per_frame": 3}  # a few hits per frame for the masks
    return r


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("stream") / "ds"
    D.generate(tiny_recipe(), out, workers=1, progress=False)
    return D.open(out)


@pytest.fixture(scope="module")
def streamed():
    return list(D.stream(tiny_recipe(), batch=3, electrons=True))


def test_stream_items_are_the_dataset_frames(tiny_dataset, streamed):
    """Same code, same seed: the streamed frame k is the dataset's frame k, bit for bit (DN, the
    EXR's electrons, the truth JSON)."""
    assert [b["frame"].tolist() for b in streamed] == [[0, 1, 2], [3, 4]]
    for b in streamed:
        for i, k in enumerate(b["frame"]):
            rec = tiny_dataset[int(k)]
            np.testing.assert_array_equal(b["image"][i], rec.dn)
            np.testing.assert_array_equal(b["electrons"][i], rec.electrons)
            assert b["truth"][i] == rec.truth


def test_stream_independent_of_batch_size_and_shard(streamed):
    ones = list(D.stream(tiny_recipe(), batch=1, start=1, stop=4))
    assert [b["frame"].tolist() for b in ones] == [[1], [2], [3]]
    by_frame = {int(k): b["image"][i] for b in streamed for i, k in enumerate(b["frame"])}
    for b in ones:
        np.testing.assert_array_equal(b["image"][0], by_frame[int(b["frame"][0])])
    halves = [list(D.stream(tiny_recipe(), batch=2, shard=(i, 2))) for i in range(2)]
    assert [[b["frame"].tolist() for b in h] for h in halves] == [[[0, 1], [4]], [[2, 3]]]
    for h in halves:
        for b in h:
            for i, k in enumerate(b["frame"]):
                np.testing.assert_array_equal(b["image"][i], by_frame[int(k)])


def test_labels_are_the_truth(streamed):
    b = streamed[0]
    n, h, w = b["image"].shape
    assert set(b) == set(LABELS)
    for i, t in enumerate(b["truth"]):
        s = int(b["star_count"][i])
        assert s == len(t["stars"]) and s > 0
        assert b["star_hip"][i, :s].tolist() == [r["hip"] for r in t["stars"]]
        assert (b["star_hip"][i, s:] == -1).all() and np.isnan(b["star_xy"][i, s:]).all()
        np.testing.assert_array_equal(b["star_xy"][i, :s], [r["xy"] for r in t["stars"]])
        np.testing.assert_array_equal(b["star_v_mag"][i, :s], [r["v_mag"] for r in t["stars"]])
        np.testing.assert_array_equal(b["q_cam_icrs"][i], t["attitude"]["q_cam_icrs"])
        pixels = {(p[0], p[1]) for hit in t["cosmic_rays"] for p in hit["pixels"]}
        assert len(pixels) > 0 and int(b["cosmic_ray_mask"][i].sum()) == len(pixels)
        assert all(b["cosmic_ray_mask"][i, r, c] for r, c in pixels)
        for body in t["bodies"]:
            j = b["body_names"].index(body["name"])
            assert b["body_radius_px"][i, j] == 0.5 * body["angular_diameter_px"]
            assert bool(b["body_in_fov"][i, j]) == body["in_fov"]
    # the charge of the masked pixels is in the electrons image, beyond the expected signal
    assert b["electrons"][b["cosmic_ray_mask"]].min() > 100.0
    assert np.linalg.norm(b["q_cam_icrs"], axis=1) == pytest.approx(1.0, abs=1e-12)


def test_stream_refuses_bad_arguments():
    for kwargs, words in (({"device": "tpu"}, "device = 'tpu' is not allowed"),
                          ({"batch": 0}, "batch = 0 is not allowed"),
                          ({"stop": 99}, "expected 0 <= start <= stop <= 5"),
                          ({"shard": (2, 2)}, "shard = (2, 2) is not allowed")):
        with pytest.raises(DatasetError) as err:
            next(D.stream(tiny_recipe(), **kwargs))
        assert words in str(err.value) and "\n" not in str(err.value)


def test_stream_on_a_missing_cuda_says_so_in_one_line():
    if jit_backend.probe_cuda().available:
        pytest.skip("CUDA works here")
    from skynav.renderer import BackendUnavailableError

    with pytest.raises(BackendUnavailableError) as err:
        next(D.stream(tiny_recipe(), device="cuda"))
    assert "cuda" in str(err.value) and "\n" not in str(err.value)


@pytest.mark.skipif(not jit_backend.llvm_available(), reason="Dr.Jit's LLVM backend does not work here")
def test_stream_on_the_llvm_device_runs_the_batched_program(streamed):
    """device='llvm': the batched frame program, its arrays Dr.Jit tensors: the dataset's
    electrons and truth, its DN the per-frame path's but for the rare rounding of the Poisson
    inversion (tests/renderer/test_batch.py)."""
    import drjit as dr

    b = next(D.stream(tiny_recipe(), batch=3, device="llvm", electrons=True))
    ref = streamed[0]
    assert dr.backend_v(b["image"]) == dr.JitBackend.LLVM and tuple(b["image"].shape) == ref["image"].shape
    image = np.from_dlpack(b["image"])
    assert np.count_nonzero(image != ref["image"]) <= image.size * 1e-4
    np.testing.assert_array_equal(b["electrons"].numpy(), ref["electrons"])
    np.testing.assert_array_equal(b["star_xy"].numpy(), ref["star_xy"])
    for got, want in zip(b["truth"], ref["truth"]):
        assert got["render"]["sensor_program"] == "batch"
        assert {k: v for k, v in got.items() if k != "render"} == {k: v for k, v in want.items() if k != "render"}


def test_torch_adapter_shares_the_arrays(streamed):
    torch = pytest.importorskip("torch")
    batches = list(torch.utils.data.DataLoader(D.torch_dataset(tiny_recipe(), batch=3, electrons=True),
                                               batch_size=None, num_workers=0))
    assert [b["frame"].tolist() for b in batches] == [[0, 1, 2], [3, 4]]
    for b, ref in zip(batches, streamed):
        assert isinstance(b["image"], torch.Tensor) and b["image"].shape == ref["image"].shape
        np.testing.assert_array_equal(b["image"].numpy(), ref["image"])
        np.testing.assert_array_equal(b["electrons"].numpy(), ref["electrons"])
        assert b["cosmic_ray_mask"].dtype == torch.bool and b["truth"] == ref["truth"]
    arr = streamed[0]["star_xy"]
    assert np.shares_memory(torch.from_dlpack(arr).numpy(), arr)  # DLPack: no copy


def test_torch_workers_share_the_batches_and_make_the_same_frames(streamed):
    """Two spawned DataLoader workers: every batch once, each frame the one of its index."""
    torch = pytest.importorskip("torch")
    loader = torch.utils.data.DataLoader(D.torch_dataset(tiny_recipe(), batch=2), batch_size=None, num_workers=2,
                                         multiprocessing_context="spawn")
    got = {int(k): img.numpy() for b in loader for k, img in zip(b["frame"], b["image"])}
    assert sorted(got) == list(range(5))
    for b in streamed:
        for i, k in enumerate(b["frame"]):
            np.testing.assert_array_equal(got[int(k)], b["image"][i])


def test_jax_adapter(streamed):
    pytest.importorskip("jax")
    b = next(D.jax_batches(tiny_recipe(), batch=3))
    np.testing.assert_array_equal(np.asarray(b["image"]), streamed[0]["image"])
    # JAX keeps float64 only with jax_enable_x64; by default it rounds to float32
    np.testing.assert_array_equal(np.asarray(b["star_xy"]), streamed[0]["star_xy"].astype(np.asarray(b["star_xy"]).dtype))
