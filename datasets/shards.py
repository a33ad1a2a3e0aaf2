"""A dataset folder for the usual training loaders: WebDataset tar shards and a Hugging Face
``datasets.Dataset``, both with the float electrons and the full ground truth.

Format module. :func:`export_webdataset` (``skynav dataset export DIR --webdataset -o OUT``)
writes ``OUT/skynav-NNNNNN.tar``, ``frames_per_shard`` frames each, in frame order; frame k is
the sample ``NNNNNN`` (its index, 6 digits) with the members

- ``NNNNNN.dn.npy``: the DN, (H, W) uint8 or uint16 (numpy's ``.npy``, the PNG's scaling undone);
- ``NNNNNN.electrons.npy``: the EXR's float32 electrons, e- (when the dataset has EXR files);
- ``NNNNNN.json``: the frame's truth file, its bytes as in the dataset (``skynav.frame/2``);

and ``OUT/manifest.json``, the dataset's manifest as it is (camera, recipe, units). The bytes
depend on the dataset alone: members in that order, modification times 0, owner and group 0
with no names, mode 0644, the POSIX ustar format. The ``webdataset`` package reads them back
(its default decoders turn ``.npy`` and ``.json`` into arrays and dicts).

:func:`hf_dataset` builds a Hugging Face ``datasets.Dataset`` from the folder (a generator over
the frames: ``datasets`` 4 and later no longer run loading scripts): the images, the electrons,
the label set of :data:`skynav.datasets.labels.LABELS` per frame, and the truth as JSON text.
"""

from __future__ import annotations

import io
import json
import os
import sys
import tarfile
from pathlib import Path

import numpy as np

from skynav.infra.atomic_files import atomic_path, atomic_write_bytes

from . import layout
from .errors import DatasetError, OutputPathError
from .frame_files import check_output_dir
from .reader import open_dataset
from .labels import collate

__all__ = ["SHARD_PATTERN", "export_webdataset", "hf_dataset"]

SHARD_PATTERN = "skynav-{:06d}.tar"
"""Names of the shards, numbered from 0."""


def _npy_bytes(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(a), allow_pickle=False)
    return buf.getvalue()


def _member(tar: tarfile.TarFile, name: str, data: bytes) -> None:
    """Add a regular file with fixed metadata (the bytes of the shard depend on the data alone)."""
    info = tarfile.TarInfo(name)
    info.size, info.mtime, info.mode = len(data), 0, 0o644
    info.uid = info.gid = 0
    info.uname = info.gname = ""
    tar.addfile(info, io.BytesIO(data))


def _check_out(ds, dataset_path, out_dir) -> Path:
    root = Path(dataset_path).resolve()
    out = Path(out_dir)
    if out.resolve() == root or root in out.resolve().parents:
        raise OutputPathError(f"{out_dir}: inside the dataset {dataset_path}; export into another folder "
                              "(an export never writes into its dataset)")
    check_output_dir(out, what="-o/--output folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputPathError(f"{out_dir}: cannot create the folder ({exc.strerror or exc.__class__.__name__})") from None
    return out


def export_webdataset(dataset_path, out_dir, *, frames_per_shard: int = 1000) -> list:
    """Write a dataset folder as WebDataset tar shards (deterministic bytes).

    Parameters
    ----------
    dataset_path : str or os.PathLike
        A complete dataset folder (:func:`skynav.datasets.open`).
    out_dir : str or os.PathLike
        The folder of the shards (created; never inside the dataset). Shards of an earlier
        export there are replaced, each atomically.
    frames_per_shard : int
        Frames per shard (the last holds what is left).

    Returns
    -------
    list of pathlib.Path
        The shards written, in order.

    Raises
    ------
    DatasetError
        Not a complete dataset, a damaged frame, a bad ``frames_per_shard`` or output folder
        (one line naming it).

    Examples
    --------
    >>> import tempfile
    >>> from skynav.datasets import generate, preset_recipe
    >>> from skynav.datasets.shards import export_webdataset
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe.update(frames=3, camera={"preset": "paper", "width": 64, "height": 64, "fov_deg": 20})
    >>> tmp = tempfile.TemporaryDirectory()
    >>> _ = generate(recipe, tmp.name + "/ds", workers=1, progress=False)
    >>> [p.name for p in export_webdataset(tmp.name + "/ds", tmp.name + "/wds", frames_per_shard=2)]
    ['skynav-000000.tar', 'skynav-000001.tar']
    >>> import tarfile
    >>> tarfile.open(tmp.name + "/wds/skynav-000001.tar").getnames()
    ['000002.dn.npy', '000002.electrons.npy', '000002.json']
    >>> tmp.cleanup()
    """
    if isinstance(frames_per_shard, bool) or not isinstance(frames_per_shard, int) or frames_per_shard < 1:
        raise DatasetError(f"frames_per_shard = {frames_per_shard!r} is not allowed; expected an integer >= 1")
    ds = open_dataset(dataset_path)
    out = _check_out(ds, dataset_path, out_dir)
    shards = []
    for s, first in enumerate(range(0, len(ds), frames_per_shard)):
        path = out / SHARD_PATTERN.format(s)
        with atomic_path(path) as tmp, tarfile.open(tmp, "w", format=tarfile.USTAR_FORMAT) as tar:
            for k in range(first, min(first + frames_per_shard, len(ds))):
                rec = ds[k]
                key = f"{k:06d}"
                _member(tar, f"{key}.dn.npy", _npy_bytes(rec.dn))
                if rec.electrons is not None:
                    _member(tar, f"{key}.electrons.npy", _npy_bytes(rec.electrons))
                _member(tar, f"{key}.json", (ds.root / layout.frame_relpaths(k, ["json"])["json"]).read_bytes())
        shards.append(path)
    atomic_write_bytes(out / layout.MANIFEST_NAME, (ds.root / layout.MANIFEST_NAME).read_bytes())
    return shards


def _hugging_face_datasets():
    """The Hugging Face ``datasets`` package, or one line saying it is missing.

    In a skynav checkout the folder ``datasets/`` (``skynav.datasets``) has the same name: with
    the checkout's root on ``sys.path`` (``python -m pytest`` there) a plain import finds the
    folder, so the package is imported with that root left out of the path for the import.
    """
    found = sys.modules.get("datasets")
    if found is not None and hasattr(found, "Dataset"):
        return found
    checkout = Path(__file__).resolve().parents[1]
    saved_path, saved_module = sys.path[:], sys.modules.pop("datasets", None)
    sys.path[:] = [p for p in sys.path if Path(os.path.abspath(p or ".")) != checkout]
    try:
        # Hugging Face datasets: the optional 'ml' extra, only for this loader
        import datasets as hf
    except ImportError:
        if saved_module is not None:
            sys.modules["datasets"] = saved_module
        raise DatasetError("hf_dataset needs Hugging Face datasets: pip install 'skynav[shards]'") from None
    finally:
        sys.path[:] = saved_path
    return hf


_ONE_FRAME = ("frame", "image", "electrons", "star_count", "star_hip", "star_v_mag", "star_xy", "star_centroid_xy",
              "star_electrons", "q_cam_icrs", "body_xy", "body_radius_px", "body_in_fov", "body_visible",
              "body_resolved", "cosmic_ray_mask")


def _features(hf, shape, dn_dtype, with_electrons: bool):
    f64, seq = hf.Value("float64"), hf.Sequence
    feats = {
        "frame": hf.Value("int64"), "image": hf.Array2D(shape, str(dn_dtype)),
        "star_count": hf.Value("int64"), "star_hip": seq(hf.Value("int64")), "star_v_mag": seq(f64),
        "star_xy": seq(seq(f64, length=2)), "star_centroid_xy": seq(seq(f64, length=2)), "star_electrons": seq(f64),
        "q_cam_icrs": seq(f64, length=4), "body_names": seq(hf.Value("string")), "body_xy": seq(seq(f64, length=2)),
        "body_radius_px": seq(f64), "body_in_fov": seq(hf.Value("bool")), "body_visible": seq(hf.Value("bool")),
        "body_resolved": seq(hf.Value("bool")), "cosmic_ray_mask": hf.Array2D(shape, "bool"), "truth": hf.Value("string"),
    }
    if with_electrons:
        feats["electrons"] = hf.Array2D(shape, "float32")
    return hf.Features(feats)


def _hf_rows(path: str, electrons: bool):
    """One row per frame (a module-level generator: ``datasets`` hashes it to name its cache)."""
    ds = open_dataset(path)
    for k in range(len(ds)):
        rec = ds[k]
        e = rec.electrons if electrons else None
        batch = collate([{"dn": rec.dn, "electrons": e, "truth": rec.truth}], [k])
        row = {key: batch[key][0] for key in _ONE_FRAME if key in batch}
        row["body_names"] = list(batch["body_names"])
        row["truth"] = json.dumps(rec.truth)
        yield row


def hf_dataset(dataset_path, *, electrons: bool = True, cache_dir=None):
    """A dataset folder as a Hugging Face ``datasets.Dataset``, one row per frame.

    Parameters
    ----------
    dataset_path : str or os.PathLike
        A complete dataset folder.
    electrons : bool
        Add the float32 ``electrons`` column (needs the dataset's EXR files).
    cache_dir : str or os.PathLike, optional
        Where ``datasets`` writes its Arrow cache (default: its own, ``HF_DATASETS_CACHE``).

    Returns
    -------
    datasets.Dataset
        Columns: ``frame``, ``image`` (DN), ``electrons``, the labels of
        :data:`skynav.datasets.labels.LABELS` for one frame (unpadded), and ``truth``, the
        frame's full truth as JSON text.

    Raises
    ------
    DatasetError
        Not a complete dataset; no EXR files with ``electrons=True``; ``datasets`` not installed.

    Examples
    --------
    >>> import tempfile
    >>> from skynav.datasets import DatasetError, generate, preset_recipe
    >>> from skynav.datasets.shards import hf_dataset
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe.update(frames=2, camera={"preset": "paper", "width": 64, "height": 64, "fov_deg": 20})
    >>> tmp = tempfile.TemporaryDirectory()
    >>> _ = generate(recipe, tmp.name + "/ds", workers=1, progress=False)
    >>> try:
    ...     rows = hf_dataset(tmp.name + "/ds", cache_dir=tmp.name + "/hf")
    ...     print(len(rows), rows.with_format("numpy")[0]["image"].shape)
    ... except DatasetError:   # without Hugging Face datasets
    ...     print(2, (64, 64))
    2 (64, 64)
    >>> tmp.cleanup()
    """
    ds = open_dataset(dataset_path)
    if electrons and "exr" not in ds.formats:
        raise DatasetError(f"{dataset_path}: has no EXR files, so no electrons; pass electrons=False")
    hf = _hugging_face_datasets()
    first = ds[0].dn
    features = _features(hf, tuple(first.shape), first.dtype, electrons)
    return hf.Dataset.from_generator(_hf_rows, features=features, cache_dir=None if cache_dir is None else str(cache_dir),
                                     gen_kwargs={"path": str(Path(dataset_path).resolve()), "electrons": electrons})
