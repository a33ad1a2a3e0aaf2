"""Reading datasets: ``skynav.datasets.open(path)``.

Adapter module. :func:`open_dataset` validates the manifest and refuses a folder whose manifest
does not say ``"complete": true`` (a half-written or interrupted dataset) with a message saying
how far it got and how to finish it. Frames are read lazily, three ways:

- ``ds[k]`` (negative indices allowed) and iteration give :class:`FrameRecord` objects whose
  ``dn`` and ``truth`` (the JSON dict) are read at once and whose float images (``electrons``,
  ``irradiance_w_m2``) are read from the EXR on first access;
- ``ds.observation(k)``: what the navigation pipeline may see, an
  :class:`~skynav.datasets.observation.Observation` (DN, epoch, exposure, calibrated camera) with
  no ground truth;
- ``ds.truth(k)``: the typed ground truth, :class:`~skynav.datasets.frame_truth.FrameTruth`,
  for scoring code.

Reading loads no renderer, Mitsuba or Dr.Jit code (``tests/test_architecture.py``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from skynav.infra.errors import SkynavError

from . import layout
from .data_keys import camera_from_record, note_unknown_keys, unknown_keys
from .errors import (
    DatasetError,
    FrameIndexError,
    IncompleteDatasetError,
    OutputFormatError,
    TruthSchemaError,
)
from .frame_files import read_exr, read_png
from .frame_truth import FrameTruth
from .journal import decode_problem
from .observation import make_observation
from .truth_schema import FRAME_SCHEMA, MANIFEST_SCHEMA, read_truth_json, schema_problems

__all__ = ["Dataset", "FrameRecord", "open_dataset", "read_image_dn", "read_frame_pair"]


def read_image_dn(path) -> np.ndarray:
    """DN of one image file outside a dataset (``bench ip`` folders, ``bench nav --images``).

    A greyscale PNG gives its DN through :func:`skynav.datasets.frame_files.read_png`: scaled
    files (``sBIT``, skynav after 0.3.0) are unscaled, raw ones returned as stored; a colour
    PNG gives the mean of its RGB channels (float). Raises ``OSError`` for an unreadable file.
    """
    try:
        return read_png(path)
    except OutputFormatError:  # not greyscale: read as colour, the mean of R, G, B
        from PIL import Image

        with Image.open(path) as im:
            a = np.asarray(im.convert("RGB"), dtype=float)
        return a.mean(axis=-1)


def read_frame_pair(png_path, json_path, *, index: int):
    """``(observation, truth dict)`` of one frame outside a dataset: a PNG and its JSON in the
    frame schema (``bench ip`` folders; written by skynav or by another program).

    The observation is built as :meth:`Dataset.observation` builds it
    (:func:`~skynav.datasets.observation.make_observation`): the camera from the JSON's
    ``camera`` (focal length, pixel pitch, principal point, distortion, exposure), the epoch from
    ``epoch``. A camera without ``sensor`` gets one of the JSON's ``bit_depth``. Raises
    :class:`DatasetError` naming the file for an unreadable PNG, JSON or camera.
    """
    png_path, json_path = Path(png_path), Path(json_path)
    try:
        truth = json.loads(json_path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{json_path}: not a readable frame JSON ({exc.__class__.__name__})") from None
    try:
        dn = read_image_dn(png_path)  # the DN of scaled (sBIT) and raw PNGs alike
    except OSError as exc:
        raise DatasetError(f"{png_path}: not a readable PNG ({exc})") from None
    cam = truth.get("camera") if isinstance(truth, dict) else None
    if isinstance(cam, dict) and "sensor" not in cam and "bit_depth" in cam:
        truth = dict(truth, camera=dict(cam, sensor={"bit_depth": cam["bit_depth"]}))
    try:
        camera, extra = camera_from_record(truth["camera"]) if isinstance(truth, dict) else (None, [])
        # once per folder of frames (a dataset), however many of its frames carry them
        note_unknown_keys(json_path.parent, extra, f"{json_path.name}'s camera", kind="camera")
        obs = make_observation(truth, dn, index=index, camera=camera)
    except SkynavError as exc:
        raise DatasetError(f"{json_path}: {exc}") from None
    except (KeyError, TypeError, ValueError) as exc:
        raise DatasetError(f"{json_path}: the frame JSON's camera or epoch is incomplete ({exc!r}); the frame "
                           "schema needs camera.width, height, focal_length_mm, pixel_pitch_um, exposure_s, "
                           "bit_depth and epoch.tdb_iso") from None
    cam = obs.camera
    if dn.ndim != 2 or dn.shape != (cam.height, cam.width):
        raise DatasetError(f"{png_path}: a {'x'.join(map(str, dn.shape[::-1]))} image; its JSON says "
                           f"{cam.width}x{cam.height} px")
    return obs, truth


class FrameRecord:
    """One frame of a dataset (immutable): ``dn``, ``truth``, lazy ``electrons``.

    Made by indexing a :class:`Dataset` (``ds[k]``); unpacks as ``dn, truth = ds[k]``.

    Parameters
    ----------
    index : int
        Frame number in the dataset.
    dn : ndarray, shape (H, W), uint8 or uint16
        Digital counts, DN (read-only; the PNG's sBIT scaling undone).
    truth : dict
        Ground truth, schema ``skynav.frame/2`` (docs/conventions.md "Files").
    exr_path : path-like, optional
        The frame's EXR, read on first access to the float images (None: no EXR).

    Attributes
    ----------
    electrons : ndarray, shape (H, W), float32
        Noise-free expected signal per pixel, e- (None if the dataset has no EXR).
    irradiance_w_m2 : ndarray, shape (H, W), float32
        Irradiance at the pupil per pixel, W/m^2 (None if the dataset has no EXR).

    Examples
    --------
    >>> import tempfile
    >>> from skynav.datasets import generate, preset_recipe
    >>> from skynav.renderer import RenderOptions
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe.update(frames=2, camera={"preset": "paper", "width": 64, "height": 64, "fov_deg": 20})
    >>> tmp = tempfile.TemporaryDirectory()
    >>> summary = generate(recipe, tmp.name + "/ds", workers=1, progress=False,
    ...                    render_options=RenderOptions(backend="numpy"))
    >>> from skynav.datasets import open
    >>> dn, truth = open(tmp.name + "/ds")[1]
    >>> dn.shape, dn.dtype.name, truth["schema"]
    ((64, 64), 'uint8', 'skynav.frame/2')
    >>> open(tmp.name + "/ds")[1].electrons.dtype.name
    'float32'
    >>> tmp.cleanup()
    """

    __slots__ = ("index", "dn", "truth", "_exr_path", "_exr")

    def __init__(self, *, index: int, dn: np.ndarray, truth: dict, exr_path=None):
        if dn is not None:
            dn.setflags(write=False)
        object.__setattr__(self, "index", int(index))
        object.__setattr__(self, "dn", dn)
        object.__setattr__(self, "truth", truth)
        object.__setattr__(self, "_exr_path", exr_path)
        object.__setattr__(self, "_exr", None)

    def __setattr__(self, name, value):
        raise AttributeError(f"FrameRecord is immutable; cannot set {name!r}")

    def _channels(self):
        if self._exr is None and self._exr_path is not None:
            object.__setattr__(self, "_exr", read_frame_exr(self._exr_path, self._shape(), index=self.index))
        return self._exr

    def _shape(self):
        """(H, W) the frame's images have: the DN's, else the truth camera's (None if neither says)."""
        if self.dn is not None:
            return tuple(self.dn.shape)
        cam = self.truth.get("camera") if isinstance(self.truth, dict) else None
        h, w = (cam.get("height"), cam.get("width")) if isinstance(cam, dict) else (None, None)
        ok = all(isinstance(v, int) and not isinstance(v, bool) for v in (h, w))
        return (h, w) if ok else None

    @property
    def electrons(self):
        """Noise-free expected signal per pixel, e-, (H, W) float32, or None without an EXR."""
        ch = self._channels()
        return None if ch is None else ch["electrons"]

    @property
    def irradiance_w_m2(self):
        """Irradiance at the pupil per pixel, W/m^2, (H, W) float32, or None without an EXR."""
        ch = self._channels()
        return None if ch is None else ch.get("irradiance_w_m2")

    def __iter__(self):  # (image, truth) unpacking
        return iter((self.dn, self.truth))

    def __repr__(self) -> str:
        epoch = self.truth.get("epoch") if isinstance(self.truth, dict) else None
        iso = epoch.get("tdb_iso") if isinstance(epoch, dict) else None
        dn = "None" if self.dn is None else f"{self.dn.dtype}{self.dn.shape}"
        return f"FrameRecord(index={self.index}, dn={dn}, epoch={iso!r})"


def read_frame_exr(path, shape, *, index: int) -> dict:
    """Channels of a frame's EXR, read-only, checked: an ``electrons`` channel, every channel a
    2-D array of numbers of the frame's ``shape`` (H, W). :class:`DatasetError` naming the file
    for anything else (an unreadable file, one with no parts or no ``electrons``, a deep image)."""
    path = Path(path)
    try:
        channels = read_exr(path)
    except FileNotFoundError:
        raise DatasetError(f"{path}: frame {index}'s EXR is missing; run `skynav dataset verify`") from None
    except Exception as exc:  # noqa: BLE001 - OpenEXR raises RuntimeError, ValueError, IndexError for damaged files
        raise DatasetError(f"{path}: frame {index}'s EXR is not readable ({exc.__class__.__name__}: "
                           f"{' '.join(str(exc).split())[:100]}); run `skynav dataset verify`") from None
    if "electrons" not in channels:
        have = ", ".join(sorted(channels)) or "none"
        raise DatasetError(f"{path}: frame {index}'s EXR has no electrons channel (channels: {have}); "
                           "run `skynav dataset verify`")
    for name, a in channels.items():
        a = np.asarray(a)
        if a.dtype.kind not in "fiu" or a.ndim != 2 or (shape is not None and a.shape != tuple(shape)):
            got = f"{a.dtype.kind == 'O' and 'deep ' or ''}{'x'.join(map(str, a.shape[::-1])) or 'no'} px of {a.dtype}"
            want = f"{shape[1]}x{shape[0]} px" if shape is not None else "a 2-D image"
            raise DatasetError(f"{path}: frame {index}'s EXR channel {name} holds {got}; the frame is {want} of "
                               "numbers; run `skynav dataset verify`")
        a.setflags(write=False)
        channels[name] = a
    return channels


class Dataset:
    """A complete dataset folder, read lazily (made by :func:`open_dataset`).

    ``len(ds)`` frames; ``ds[k]`` (negative indices and slices allowed) and iteration give
    :class:`FrameRecord` objects; :meth:`observation` gives what the navigation pipeline may
    see, :meth:`truth` the typed ground truth.

    Parameters
    ----------
    root : path-like
        The dataset folder.
    manifest : dict
        Its ``manifest.json`` (schema ``skynav.dataset/1``).

    Attributes
    ----------
    root : pathlib.Path
        The dataset folder.
    manifest : dict
        The manifest.
    recipe : dict
        The normalised recipe the dataset was made from.
    formats : tuple of str
        The file formats of each frame (``png``, ``exr``, ``json``, ``fits``).

    Examples
    --------
    >>> import tempfile
    >>> from skynav.datasets import generate, preset_recipe
    >>> from skynav.renderer import RenderOptions
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe.update(frames=2, camera={"preset": "paper", "width": 64, "height": 64, "fov_deg": 20})
    >>> tmp = tempfile.TemporaryDirectory()
    >>> summary = generate(recipe, tmp.name + "/ds", workers=1, progress=False,
    ...                    render_options=RenderOptions(backend="numpy"))
    >>> from skynav.datasets import open
    >>> ds = open(tmp.name + "/ds")
    >>> len(ds), ds.formats, ds.camera.width
    (2, ('png', 'exr', 'json'), 64)
    >>> obs = ds.observation(-1)
    >>> obs.dn.shape, obs.exposure_s
    ((64, 64), 0.4)
    >>> ds.truth(0).camera["width"]
    64
    >>> tmp.cleanup()
    """

    def __init__(self, root, manifest: dict):
        self.root = Path(root)
        self.manifest = manifest
        self.recipe = manifest["recipe"]
        self.formats = tuple(manifest["formats"])
        self._n = int(manifest["counts"]["frames"])
        self._index = None
        self._noted = set()  # what unknown frame keys were said of (once per dataset each)

    def __len__(self) -> int:
        return self._n

    def _frame_index(self, k) -> int:
        if isinstance(k, (bool, np.bool_)) or not isinstance(k, (int, np.integer)):
            raise FrameIndexError(f"frame index must be an integer, got {type(k).__name__}")
        i = int(k) + self._n if k < 0 else int(k)
        if not 0 <= i < self._n:
            raise FrameIndexError(f"frame {k} out of range; the dataset has {self._n} frames (0..{self._n - 1})")
        return i

    def _read(self, i: int, *, dn: bool = True):
        """(truth dict, DN or None, relative paths) of frame ``i``."""
        rel = layout.frame_relpaths(i, self.formats)
        try:
            truth = read_truth_json(self.root / rel["json"])
            image = read_png(self.root / rel["png"]) if dn and "png" in rel else None
        except FileNotFoundError as exc:
            raise DatasetError(f"{self.root}: frame {i} is missing ({Path(exc.filename).name}); run verify()") from None
        except SkynavError:
            raise
        except Exception as exc:  # noqa: BLE001 - a damaged file (0 bytes, truncated, corrupt)
            bad = next((r for r in rel.values() if decode_problem(self.root / r) is not None), rel.get("png", rel["json"]))
            raise DatasetError(f"{self.root / bad}: frame {i} is damaged ({exc.__class__.__name__}); "
                               f"run `skynav dataset verify`") from None
        if "truth" not in self._noted:
            extra = unknown_keys(truth, FRAME_SCHEMA)
            if extra:
                self._noted.add("truth")
                note_unknown_keys(self.root, extra, f"frame {i}'s truth", kind="truth")
        return truth, image, rel

    def __getitem__(self, k) -> FrameRecord:
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(self._n))]
        i = self._frame_index(k)
        truth, dn, rel = self._read(i)
        exr = self.root / rel["exr"] if "exr" in rel else None
        return FrameRecord(index=i, dn=dn, truth=truth, exr_path=exr)

    def observation(self, k, *, calibration_error=None):
        """What the navigation pipeline may see of frame ``k``: no ground truth.

        Parameters
        ----------
        k : int
            Frame index (negative counts from the end).
        calibration_error : skynav.datasets.observation.CalibrationErrorModel, optional
            Perturb the camera by this model (default: the true camera).

        Returns
        -------
        skynav.datasets.observation.Observation
            ``dn`` (H, W), ``epoch_tdb_s`` (TDB s past J2000; ``.epoch`` as astropy ``Time``),
            ``exposure_s``, ``camera`` as calibrated, ``calibration_error``.
        """
        i = self._frame_index(k)
        truth, dn, _ = self._read(i)
        if dn is None:
            raise DatasetError(f"{self.root}: frame {i} has no DN image (formats: {', '.join(self.formats)})")
        try:
            camera, extra = camera_from_record(truth["camera"])
            if extra and "camera" not in self._noted:
                self._noted.add("camera")
                note_unknown_keys(self.root, extra, f"frame {i}'s camera", kind="camera")
            return make_observation(truth, dn, index=i, calibration_error=calibration_error, camera=camera)
        except (SkynavError, KeyError, TypeError, ValueError, IndexError, AttributeError) as exc:
            raise self._truth_error(i, exc) from None

    def truth(self, k, *, validate: bool = True):
        """Typed ground truth of frame ``k`` (for scoring code).

        ``ds[k].truth`` stays the plain dict.

        Parameters
        ----------
        k : int
            Frame index (negative counts from the end).
        validate : bool
            Check the truth against ``frame.schema.json`` first.

        Returns
        -------
        skynav.datasets.frame_truth.FrameTruth
            The frame's truth, typed.

        Raises
        ------
        TruthSchemaError
            A truth that does not follow the schema (the file and the first JSON path).
        """
        i = self._frame_index(k)
        truth, _, rel = self._read(i, dn=False)
        try:
            return FrameTruth.from_dict(truth, validate=validate, source=str(self.root / rel["json"]))
        except (SkynavError, KeyError, TypeError, ValueError, IndexError, AttributeError) as exc:
            raise self._truth_error(i, exc) from None

    def _truth_error(self, i: int, exc: Exception):
        """One-line :class:`TruthSchemaError` for a frame truth the reader could not use: the first
        schema problem when there is one, else the error's kind."""
        if isinstance(exc, (DatasetError, TruthSchemaError, FrameIndexError)):  # already one line naming the file
            return exc
        rel = layout.frame_relpaths(i, self.formats)["json"]
        truth = self._read(i, dn=False)[0]
        problems = schema_problems(truth, FRAME_SCHEMA) if isinstance(truth, dict) else ["the file is not a JSON object"]
        what = problems[0] if problems else (" ".join(str(exc).split())[:160] if isinstance(exc, SkynavError)
                                             else f"{exc.__class__.__name__}: {' '.join(str(exc).split())[:120]}")
        return TruthSchemaError(f"{self.root / rel}: frame {i}'s truth does not follow skynav.frame/1: {what}; "
                                "run `skynav dataset verify`", problems)

    def __iter__(self):
        for i in range(self._n):
            yield self[i]

    @property
    def index(self) -> list:
        """Rows of ``index.csv`` (one dict of strings per frame)."""
        if self._index is None:
            self._index = layout.read_index(self.root)
        return self._index

    @property
    def camera(self):
        """The dataset's camera (the manifest's ``camera``; keys this skynav does not know left out)."""
        try:
            camera, _ = camera_from_record(self.manifest["camera"])
        except SkynavError as exc:
            raise DatasetError(f"{self.root / layout.MANIFEST_NAME}: {exc}") from None
        return camera

    def __repr__(self) -> str:
        return f"Dataset({str(self.root)!r}, kind={self.recipe['kind']!r}, frames={self._n})"


def open_dataset(path) -> Dataset:
    """Open a complete dataset folder (``skynav.datasets.open`` is the same function).

    Nothing but the manifest is read here; frames are read when indexed.

    Parameters
    ----------
    path : str or os.PathLike
        The dataset folder (the one holding ``manifest.json``).

    Returns
    -------
    Dataset
        The dataset, read lazily.

    Raises
    ------
    DatasetError
        Not a dataset folder, unreadable manifest.
    IncompleteDatasetError
        The manifest does not say ``"complete": true``.

    Examples
    --------
    >>> import tempfile
    >>> from skynav.datasets import generate, preset_recipe
    >>> from skynav.renderer import RenderOptions
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe.update(frames=2, camera={"preset": "paper", "width": 64, "height": 64, "fov_deg": 20})
    >>> tmp = tempfile.TemporaryDirectory()
    >>> summary = generate(recipe, tmp.name + "/ds", workers=1, progress=False,
    ...                    render_options=RenderOptions(backend="numpy"))
    >>> from skynav.datasets import open
    >>> ds = open(tmp.name + "/ds")
    >>> len(ds), ds[0].dn.shape
    (2, (64, 64))
    >>> tmp.cleanup()
    """
    root = Path(path)
    m = layout.read_manifest(root)
    if m.get("complete") is not True:
        c = m.get("counts", {})
        done, total = c.get("frames_done"), c.get("frames")
        raise IncompleteDatasetError(
            f"{root} is an incomplete dataset ({done} of {total} frames written, manifest not complete); "
            "finish it by running generate again on the same folder", path=str(root), done=done, total=total)
    check_manifest(m, root / layout.MANIFEST_NAME)
    note_unknown_keys(root, unknown_keys(m, MANIFEST_SCHEMA), layout.MANIFEST_NAME)
    return Dataset(root, m)


def check_manifest(m: dict, where) -> None:
    """Refuse a complete manifest the reader cannot trust, in one line naming ``where``: one that
    does not follow ``manifest.schema.json`` (a key missing, a count that is not an integer >= 0, a
    number where a list belongs), has no ``json`` among its formats, or whose counts disagree with
    each other or with its file table. The file table's entries are checked by ``verify``
    (checksums), not here: opening a dataset of a million files stays cheap."""
    files = m.get("files")
    problems = schema_problems(dict(m, files={}) if isinstance(files, dict) else m, MANIFEST_SCHEMA)
    if problems:
        more = f" (+{len(problems) - 1} more)" if len(problems) > 1 else ""
        raise DatasetError(f"{where}: does not follow {MANIFEST_SCHEMA}: {problems[0]}{more}; "
                           "run `skynav dataset verify`")
    counts = m["counts"]
    if "json" not in m["formats"]:
        raise DatasetError(f"{where}: formats {m['formats']} hold no json; a dataset's frames each have a "
                           "ground-truth JSON")
    if counts["frames_done"] != counts["frames"]:
        raise DatasetError(f"{where}: says complete with {counts['frames_done']} of {counts['frames']} frames done; "
                           "run `skynav dataset verify`")
    listed = sum(1 for rel in files if rel.startswith(f"{layout.FRAMES_DIR}/") and rel.endswith(".json"))
    if listed != counts["frames"]:
        raise DatasetError(f"{where}: counts.frames is {counts['frames']} but its file table lists {listed} frame "
                           "JSON files; run `skynav dataset verify`")
