"""WebDataset shards and the Hugging Face loader of a dataset folder: read back by the other
programs (``webdataset``, ``datasets``) to the dataset's DN, electrons and truth; the shards'
bytes depend on the dataset alone."""

from __future__ import annotations

import hashlib
import json
import tarfile

import numpy as np
import pytest

import skynav.datasets as D
from skynav.__main__ import main
from skynav.datasets.shards import export_webdataset, hf_dataset

from .conftest import small_recipe

FRAMES = 100


@pytest.fixture(scope="module")
def hundred(tmp_path_factory):
    """A 100-frame dataset on a 32 x 32, 20 deg camera (fast frames), with cosmic rays."""
    r = small_recipe(FRAMES)
    r["camera"] = {"preset": "paper", "width": 32, "height": 32, "fov_deg": 20.0}
    out = tmp_path_factory.mktemp("shards") / "ds"
    D.generate(r, out, workers=1, progress=False)
    return out


def _sha(paths) -> list:
    return [hashlib.sha256(p.read_bytes()).hexdigest() for p in paths]


def test_webdataset_shards_read_back_to_the_dataset(hundred, tmp_path, capsys):
    wds = pytest.importorskip("webdataset")
    assert main(["dataset", "export", str(hundred), "--webdataset", "-o", str(tmp_path / "a"),
                 "--frames-per-shard", "40"]) == 0
    shards = sorted((tmp_path / "a").glob("*.tar"))
    assert [p.name for p in shards] == ["skynav-000000.tar", "skynav-000001.tar", "skynav-000002.tar"]
    assert (tmp_path / "a" / "manifest.json").read_bytes() == (hundred / "manifest.json").read_bytes()
    ds = D.open(hundred)
    seen = []
    for sample in wds.WebDataset([str(p) for p in shards], shardshuffle=False).decode():
        k = int(sample["__key__"])
        rec = ds[k]
        assert sample["dn.npy"].dtype == rec.dn.dtype
        np.testing.assert_array_equal(sample["dn.npy"], rec.dn)
        np.testing.assert_array_equal(sample["electrons.npy"], rec.electrons)
        assert sample["json"] == rec.truth
        seen.append(k)
    assert seen == list(range(FRAMES))
    # deterministic bytes: a second export (another folder, another time) is the same bytes
    export_webdataset(hundred, tmp_path / "b", frames_per_shard=40)
    assert _sha(shards) == _sha(sorted((tmp_path / "b").glob("*.tar")))
    with tarfile.open(shards[0]) as tar:
        info = tar.getmembers()[0]
        assert (info.mtime, info.uid, info.gid, info.uname, info.gname) == (0, 0, 0, "", "")


def test_export_refuses_its_own_dataset_and_a_bad_count(hundred, capsys):
    assert main(["dataset", "export", str(hundred), "--webdataset", "-o", str(hundred / "wds")]) == 2
    err = capsys.readouterr().err.strip()
    assert "inside the dataset" in err and "\n" not in err and not (hundred / "wds").exists()
    with pytest.raises(D.DatasetError, match="frames_per_shard = 0 is not allowed"):
        export_webdataset(hundred, hundred.parent / "x", frames_per_shard=0)


def test_hugging_face_loader_reads_the_folder(hundred, tmp_path):
    try:
        rows = hf_dataset(hundred, cache_dir=tmp_path / "hf")
    except D.DatasetError as exc:
        pytest.skip(str(exc))
    ds = D.open(hundred)
    assert len(rows) == FRAMES
    view = rows.with_format("numpy")
    for k in (0, 37, FRAMES - 1):
        row, rec = view[k], ds[k]
        assert int(row["frame"]) == k
        np.testing.assert_array_equal(row["image"], rec.dn)
        np.testing.assert_array_equal(row["electrons"], rec.electrons)
        assert json.loads(row["truth"]) == rec.truth
        plain = rows[k]  # python values: the float64 labels as they are (numpy's format rounds them)
        assert plain["star_hip"] == [s["hip"] for s in rec.truth["stars"]]
        assert plain["star_xy"] == [s["xy"] for s in rec.truth["stars"]]
        assert plain["q_cam_icrs"] == rec.truth["attitude"]["q_cam_icrs"]
        hits = {(p[0], p[1]) for h in rec.truth["cosmic_rays"] for p in h["pixels"]}
        assert int(row["cosmic_ray_mask"].sum()) == len(hits)
