"""Frame files: OpenEXR, PNG, FITS with a TAN WCS.

Adapter module: the one place that talks to OpenEXR, Pillow and
``astropy.io.fits`` for frames. The renderer returns frames in memory
(:class:`skynav.renderer.render.Frame`) and does no file I/O; :func:`write_frame` turns one into
files, for ``skynav render`` and for the dataset runner alike. Nothing here imports the
renderer. File contracts are those of docs/conventions.md "Files":

- **EXR**: float32 named channels (``electrons``, ``irradiance_w_m2``, ...), optional uint32
  ``source_id``. Compression is RLE (run-length on bytes, EXR 1.0): lossless for float32 and
  uint32, deterministic, and read by every EXR tool (the choice among OpenEXR's compressions is
  measured in docs/performance.md). The pixels of files whose channels are all 4-byte are written
  by :mod:`skynav.datasets.exr_rle` inside OpenEXR's own header; ``_exr_bytes(..., sparse=False)``
  is OpenEXR's encoder, its reference.
- **PNG**: greyscale, uint8 for bit depth <= 8, uint16 for 9-16 bit; DN of fewer bits than the
  sample (a 12-bit sensor, a 10-bit screen) are scaled to the full range with an ``sBIT`` chunk
  naming the significant bits (the PNG specification's way, section 12.4), so viewers show them;
  :func:`read_png` returns the DN, of these files and of the raw ones of skynav <= 0.3.0. The
  file is written by :mod:`skynav.datasets.png_rle` (Pillow is its reference).
- **FITS**: the image as given with a TAN WCS and the standard keywords,
  :mod:`skynav.datasets.fits_files`.
- **JSON** ground truth: :mod:`skynav.datasets.truth_schema`.

Atomicity: each writer encodes to memory and hands the bytes to
:func:`~skynav.infra.atomic_files.atomic_write_bytes` (temp file in the same directory, ``fsync``,
``os.replace``, directory ``fsync``), so a reader sees either the old file or the complete new one,
never a partial file, and a failure leaves no temp file behind.

Determinism: identical inputs give identical bytes (same library versions): no writer embeds
a date, a host name or a random value. Tests pin this by SHA-256.

Readers accept a path or a binary file object, so a caller may read from memory as well as from disk.
"""

from __future__ import annotations

import io
import os
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from PIL import Image

from skynav.infra.atomic_files import atomic_write_bytes, open_binary
from skynav.infra.errors import ConfigValueError
from skynav.infra.threads import thread_budget
from skynav.scenes.camera import Camera

from .errors import OutputFormatError, OutputPathError
from .exr_rle import reference_exr_bytes, sparse_exr_bytes
from .fits_files import fits_bytes, fits_frame_header
from .fits_sip import sky_wcs_header
from .png_rle import png_rle_bytes
from .truth_schema import truth_json_bytes

__all__ = [
    "FRAME_FORMATS",
    "check_output_dir",
    "check_stem",
    "OutputFormatError",
    "write_exr",
    "read_exr",
    "read_exr_header",
    "PNG_SCALING",
    "PNG_SCALING_KEY",
    "scale_dn_to_png",
    "unscale_png_to_dn",
    "write_png",
    "read_png",
    "read_png_layout",
    "write_frame",
    "encode_frame",
    "write_files",
    "frame_file_bytes",
    "png_bytes",
    "exr_bytes",
]

#: File formats :func:`write_frame` knows, by file extension.
FRAME_FORMATS = ("png", "exr", "json", "fits")


_SYSTEM_DIRS = ("/proc", "/sys", "/dev")


def check_output_dir(directory, *, what: str = "output folder") -> Path:
    """Refuse an output folder that cannot hold files, with one line naming it.

    Checked before any work: the path (or one of its parents) is an existing file, lies in a
    kernel file system (``/proc``, ``/sys``, ``/dev``), or its nearest existing folder is not
    writable.

    Raises
    ------
    OutputPathError
    """
    d = Path(os.path.abspath(os.fspath(directory)))
    for sysdir in _SYSTEM_DIRS:
        if str(d) == sysdir or str(d).startswith(sysdir + "/"):
            raise OutputPathError(f"{directory}: {what} is in a kernel file system ({sysdir}); choose a folder on disk")
    probe = d
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if probe.exists() and not probe.is_dir():
        where = "is an existing file" if probe == d else f"lies under a file ({probe})"
        raise OutputPathError(f"{directory}: {what} {where}; give a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise OutputPathError(f"{directory}: {what} is not writable (no write permission on {probe})")
    return d


def check_stem(stem, *, what: str = "file name") -> str:
    """Refuse a file stem that is not a plain visible name (empty, ``..``, a path, hidden).

    Raises
    ------
    OutputPathError
    """
    if not isinstance(stem, str) or not stem.strip() or "/" in stem or os.sep in stem or stem.startswith(".") \
            or "\0" in stem:
        raise OutputPathError(f"{what} {stem!r}: expected a plain file name (not empty, no '/', "
                              f"not starting with '.')")
    return stem


# ----------------------------------------------------------------------------- OpenEXR
# Attributes OpenEXR manages itself; a caller's header must not override them.
_EXR_RESERVED = frozenset(
    {"channels", "compression", "dataWindow", "displayWindow", "lineOrder", "pixelAspectRatio",
     "screenWindowCenter", "screenWindowWidth", "type", "tiles", "name", "version", "chunkCount"}
)


def _exr_channel(name, array, shape):
    a = np.asarray(array)
    if a.ndim != 2:
        raise OutputFormatError(f"EXR channel {name!r} has shape {a.shape}; expected a 2-D (H, W) array")
    if shape is not None and a.shape != shape:
        raise OutputFormatError(f"EXR channel {name!r} has shape {a.shape}; other channels are {shape}")
    if a.dtype.kind == "f":
        return np.ascontiguousarray(a, dtype=np.float32)
    if a.dtype.kind in "iub":
        if a.size and (a.min() < 0 or a.max() > np.iinfo(np.uint32).max):
            raise OutputFormatError(f"EXR channel {name!r}: integer values must fit uint32 (0..4294967295)")
        return np.ascontiguousarray(a, dtype=np.uint32)
    raise OutputFormatError(f"EXR channel {name!r} has dtype {a.dtype}; expected float or unsigned integer")


_exr_threads_set = False


def _exr_threads(OpenEXR) -> None:
    """OpenEXR's global pool: ``SKYNAV_THREADS`` (default: the cores) when >= 2, else none (a
    single helper thread is slower than compressing in the caller)."""
    global _exr_threads_set
    if not _exr_threads_set:
        n = thread_budget() or (os.cpu_count() or 1)
        OpenEXR.set_global_thread_count(n if n >= 2 else 0)
        _exr_threads_set = True


def _exr_bytes(channels: Mapping, header: Mapping | None, *, sparse: bool = True) -> bytes:
    """The EXR file's bytes, written by :mod:`skynav.datasets.exr_rle`; ``sparse=False``:
    OpenEXR's own RLE encoder for the pixels (the reference)."""
    import OpenEXR  # adapter-local import: the library is heavy and only needed here

    _exr_threads(OpenEXR)

    if not channels:
        raise OutputFormatError("write_exr needs at least one channel")
    arrays, shape = {}, None
    for name, array in channels.items():
        if not isinstance(name, str) or not name:
            raise OutputFormatError(f"EXR channel name {name!r} must be a non-empty string")
        arrays[name] = _exr_channel(name, array, shape)
        shape = arrays[name].shape
    hdr = {"compression": OpenEXR.RLE_COMPRESSION, "type": OpenEXR.scanlineimage}
    for key, value in (header or {}).items():
        if key in _EXR_RESERVED:
            raise OutputFormatError(f"EXR header key {key!r} is managed by the writer; choose another name")
        if isinstance(value, (bool, np.bool_)):
            value = int(value)
        elif isinstance(value, (int, np.integer)):
            value = int(value)
        elif isinstance(value, (float, np.floating)):
            # OpenEXR's Python binding stores a float attribute as 32-bit; keep the double exactly.
            value = repr(float(value))
        elif not isinstance(value, str):
            raise OutputFormatError(f"EXR header {key!r}: value of type {type(value).__name__}; expected str, int or float")
        hdr[str(key)] = value
    fast = sparse_exr_bytes(arrays, hdr, OpenEXR) if sparse else None
    return fast if fast is not None else reference_exr_bytes(arrays, hdr, OpenEXR)


def exr_bytes(channels: Mapping, *, header: Mapping | None = None) -> bytes:
    """Named image channels as the bytes of an OpenEXR file (what :func:`write_exr` writes)."""
    return _exr_bytes(channels, header)


def write_exr(path, channels: Mapping, *, header: Mapping | None = None) -> None:
    """Write named image channels to an OpenEXR file (RLE compression), atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Destination ``.exr``.
    channels : mapping of str to ndarray, shape (H, W)
        E.g. ``{"electrons": e, "irradiance_w_m2": irr, "source_id": ids}``. Floating arrays are
        written as float32 (float64 is rounded to float32); integer arrays as uint32 (values
        must be in 0..2**32-1). All channels share one shape.
    header : mapping of str to (str, int, float), optional
        Extra header attributes. Floats are stored as their ``repr`` string (OpenEXR's Python
        binding would round them to float32), so they come back from
        :func:`read_exr_header` as ``str``. Structural keys (``compression``, ``channels``...)
        are refused.

    Raises
    ------
    OutputFormatError
        Empty channel set, wrong shapes or dtypes, or a reserved header key.
    """
    atomic_write_bytes(path, _exr_bytes(channels, header))


def read_exr(source) -> dict:
    """Channels of an OpenEXR file, ``{name: ndarray (H, W)}`` (float32 or uint32)."""
    # OpenEXR only for EXR files: the reader imports this module for PNGs
    import OpenEXR

    with open_binary(source) as f:
        exr = OpenEXR.File(f, separate_channels=True)
        return {name: np.array(ch.pixels) for name, ch in exr.channels().items()}


def read_exr_header(source) -> dict:
    """Header attributes of an OpenEXR file (including OpenEXR's own structural ones)."""
    # OpenEXR only for EXR files: the reader imports this module for PNGs
    import OpenEXR

    with open_binary(source) as f:
        return dict(OpenEXR.File(f, header_only=True).header())


# ----------------------------------------------------------------------------- PNG
#: How DN of fewer bits than the PNG sample (e.g. 10 or 12 bit in a 16-bit PNG) are stored: scaled
#: to the PNG's full range with the PNG specification's recommended linear scaling (PNG 2nd ed.,
#: section 12.4 "Sample depth scaling"), ``stored = floor(dn * MAX / m + 1/2)`` with
#: ``m = 2**bits - 1`` and ``MAX`` = 255 or 65535, and an ``sBIT`` chunk naming the significant
#: bits. Recorded in each file by a ``tEXt`` chunk :data:`PNG_SCALING_KEY` = ``"sbit"`` and in the
#: JSON beside the files (``png_scaling``, ``significant_bits``).
PNG_SCALING = "sbit"
#: ``tEXt`` keyword of the marker (skynav's files of 0.3.0 and before have none: their DN are raw).
PNG_SCALING_KEY = "skynav.png_scaling"


def _png_container_bits(bit_depth: int) -> int:
    return 8 if bit_depth <= 8 else 16


def scale_dn_to_png(dn, bit_depth: int) -> np.ndarray:
    """DN of ``bit_depth`` bits scaled to the full range of their PNG sample (8 or 16 bit).

    ``stored = floor(dn * MAX / m + 1/2)`` (PNG specification, section 12.4, the recommended
    linear scaling), ``m = 2**bit_depth - 1``, ``MAX = 2**8 - 1`` or ``2**16 - 1``; exact integer
    arithmetic. 8- and 16-bit DN are returned unchanged. :func:`unscale_png_to_dn` inverts it
    exactly, and so does the right shift by ``container - bit_depth`` that the specification
    names for decoders (``tests/datasets/test_png_scaling.py`` checks both for every value).

    Examples
    --------
    >>> scale_dn_to_png(np.array([0, 1, 512, 1023], np.uint16), 10).tolist()
    [0, 64, 32800, 65535]
    """
    a = np.asarray(dn)
    c = _png_container_bits(bit_depth)
    if bit_depth == c:
        return a
    m, top = (1 << bit_depth) - 1, (1 << c) - 1
    return ((2 * a.astype(np.int64) * top + m) // (2 * m)).astype(a.dtype)


def unscale_png_to_dn(stored, bit_depth: int) -> np.ndarray:
    """Inverse of :func:`scale_dn_to_png`: ``dn = floor(stored * m / MAX + 1/2)``.

    Exact for every value :func:`scale_dn_to_png` writes (the rounding error of the scaling,
    at most 1/2 of a stored step, is less than 1/2 DN after division by ``MAX / m`` > 1); it
    also recovers DN scaled by left-bit replication (another spec-conforming encoder's choice).

    Examples
    --------
    >>> unscale_png_to_dn(np.array([0, 64, 32800, 65535], np.uint16), 10).tolist()
    [0, 1, 512, 1023]
    """
    a = np.asarray(stored)
    c = _png_container_bits(bit_depth)
    if bit_depth == c:
        return a
    m, top = (1 << bit_depth) - 1, (1 << c) - 1
    return ((2 * a.astype(np.int64) * m + top) // (2 * top)).astype(a.dtype)


def write_png(path, dn, *, bit_depth: int | None = None, compress_level: int = 6) -> None:
    """Write digital counts as a greyscale PNG, atomically: the bytes of :func:`png_bytes`."""
    atomic_write_bytes(path, png_bytes(dn, bit_depth=bit_depth, compress_level=compress_level))


def png_bytes(dn, *, bit_depth: int | None = None, compress_level: int = 6) -> bytes:
    """Digital counts as the bytes of a greyscale PNG file (what :func:`write_png` writes).

    Parameters
    ----------
    dn : ndarray, shape (H, W), uint8 or uint16
        Digital counts, DN. uint8 gives an 8-bit PNG, uint16 a 16-bit PNG.
    bit_depth : int, optional
        Significant bits of the DN, 1..16 (a 12-bit sensor, a 10-bit screen). When given, the
        dtype must match (uint8 for <= 8, uint16 for 9..16), every value must be
        <= ``2**bit_depth - 1``, the DN are scaled to the PNG's full range
        (:func:`scale_dn_to_png`: a 12-bit 4095 is stored as 65535, so every viewer shows the
        image), and the file carries an ``sBIT`` chunk with ``bit_depth`` and a ``tEXt``
        :data:`PNG_SCALING_KEY` = ``"sbit"``. Without it the values are stored as they are.
        :func:`read_png` gives the DN back either way.
    compress_level : int
        zlib level, 0..9 (the pixels are the same at every level). The rows are unfiltered and
        compressed with zlib's run-length strategy (:mod:`skynav.datasets.png_rle`), for which the level
        changes little.

    Raises
    ------
    OutputFormatError
        Wrong shape or dtype, or a value above the bit depth.
    """
    return _png_file_bytes(dn, bit_depth, compress_level)


def _png_file_bytes(dn, bit_depth, compress_level) -> bytes:
    """The checked bytes of :func:`write_png`."""
    a = np.asarray(dn)
    if a.ndim != 2:
        raise OutputFormatError(f"PNG image has shape {a.shape}; expected a 2-D (H, W) array of DN")
    if a.dtype not in (np.uint8, np.uint16):
        raise OutputFormatError(f"PNG image has dtype {a.dtype}; expected uint8 (bit depth <= 8) or uint16 (9-16)")
    sbit = None
    if bit_depth is not None:
        if not (isinstance(bit_depth, (int, np.integer)) and 1 <= bit_depth <= 16):
            raise OutputFormatError(f"PNG bit_depth = {bit_depth!r}; expected an integer in 1..16")
        want = np.uint8 if bit_depth <= 8 else np.uint16
        if a.dtype != want:
            raise OutputFormatError(f"PNG of bit depth {bit_depth} needs {np.dtype(want).name} DN, got {a.dtype}")
        if a.size and int(a.max()) > (1 << bit_depth) - 1:
            raise OutputFormatError(f"PNG DN max {int(a.max())} exceeds {(1 << bit_depth) - 1} for bit depth {bit_depth}")
        a = scale_dn_to_png(a, int(bit_depth))
        sbit = int(bit_depth)
    if not (isinstance(compress_level, (int, np.integer)) and 0 <= compress_level <= 9):
        raise OutputFormatError(f"PNG compress_level = {compress_level!r}; expected an integer in 0..9 (zlib's levels)")
    text = ((PNG_SCALING_KEY, PNG_SCALING),) if sbit is not None else ()
    return png_rle_bytes(a, int(compress_level), sbit=sbit, text=text)


def _png_header_chunks(data: bytes) -> dict:
    """``{chunk type: [payload, ...]}`` of the chunks before the first IDAT."""
    out, i = {}, 8
    while i + 8 <= len(data):
        n = int.from_bytes(data[i:i + 4], "big")
        kind = data[i + 4:i + 8]
        if kind == b"IDAT":
            break
        out.setdefault(kind, []).append(data[i + 8:i + 8 + n])
        i += 12 + n
    return out


def _png_layout(data: bytes, stored_max) -> dict:
    chunks = _png_header_chunks(data)
    ihdr = chunks.get(b"IHDR", [b""])[0]
    container = ihdr[8] if len(ihdr) > 8 else None
    sbit = chunks.get(b"sBIT", [b""])[0]
    bits = sbit[0] if len(sbit) == 1 else None  # greyscale sBIT is one byte
    marker = None
    for t in chunks.get(b"tEXt", []):
        key, _, value = t.partition(b"\0")
        if key == PNG_SCALING_KEY.encode():
            marker = value.decode("latin-1")
    if marker == PNG_SCALING or (marker is None and bits and container and bits < container and stored_max is not None
                                 and stored_max > (1 << bits) - 1):
        # skynav's marker, or a foreign file whose values exceed its sBIT range: by the PNG
        # specification such a file is scaled (a file written raw could not hold them)
        if not bits or not container or bits > container:
            raise OutputFormatError(f"PNG says {PNG_SCALING_KEY} = {marker!r} but has no valid sBIT chunk")
        return {"png_scaling": PNG_SCALING, "significant_bits": int(bits)}
    # no marker: skynav <= 0.3.0 (raw DN, sBIT naming the camera's bits) or a plain PNG
    return {"png_scaling": "raw", "significant_bits": int(bits) if bits else container}


def read_png_layout(source) -> dict:
    """How a PNG stores its DN: ``{"png_scaling": "sbit" | "raw", "significant_bits": int}``.

    ``"sbit"``: scaled to the full range (:func:`scale_dn_to_png`), written by skynav after 0.3.0
    (``tEXt`` :data:`PNG_SCALING_KEY`), or a foreign file with an ``sBIT`` chunk whose values
    exceed ``2**sBIT - 1``. ``"raw"``: the values are the DN (files of skynav <= 0.3.0, whose
    ``sBIT`` named the bit depth of unscaled DN, and PNGs without ``sBIT``).
    """
    with open_binary(source) as f:
        data = f.read()
    with Image.open(io.BytesIO(data)) as image:
        stored_max = int(np.asarray(image).max()) if image.width and image.height else 0
    return _png_layout(data, stored_max)


def read_png(source) -> np.ndarray:
    """DN of a greyscale PNG, shape (H, W): uint8 for 8-bit files, uint16 for 16-bit ones.

    Scaled files (:func:`read_png_layout` ``"sbit"``) are unscaled (:func:`unscale_png_to_dn`);
    raw ones (skynav <= 0.3.0, plain PNGs) are returned as stored. Either way the DN are those
    that were written.
    """
    with open_binary(source) as f:
        data = f.read()
    with Image.open(io.BytesIO(data)) as image:
        if image.mode not in ("L", "I;16", "I;16B", "I"):
            raise OutputFormatError(f"PNG mode {image.mode!r}; expected greyscale (L or I;16)")
        a = np.array(image)
    if a.dtype.kind in "iu" and a.dtype.itemsize > 2:  # mode "I": 16-bit data in int32
        a = a.astype(np.uint16)
    layout = _png_layout(data, int(a.max()) if a.size else 0)
    if layout["png_scaling"] == PNG_SCALING:
        a = unscale_png_to_dn(a, layout["significant_bits"])
    return a


# ----------------------------------------------------------------------------- one frame
def write_frame(frame, directory, stem: str, *, formats=("png", "exr", "json"), fits: bool = False) -> dict:
    """Write one in-memory frame's files atomically: ``<directory>/<stem>.<format>``.

    Parameters
    ----------
    frame : skynav.renderer.render.Frame
        Or any object with ``dn`` (H, W) uint8/uint16 DN, ``electrons`` and
        ``irradiance_w_m2`` (H, W) float32 (e-, W/m^2) and ``truth`` (the ``skynav.frame/2``
        dict).
    directory : str or os.PathLike
        Created if missing.
    stem : str
        File name without extension (``"frame"``, ``"000042"``).
    formats : sequence of str
        Any of ``png`` (DN, with the camera's bit depth in ``sBIT``), ``exr`` (``electrons``,
        ``irradiance_w_m2``), ``json`` (ground truth, canonical bytes) and ``fits`` (DN with
        the TAN WCS of the truth's ``camera.K`` and ``attitude.R_cam_icrs``).
    fits : bool
        Also write FITS when ``formats`` does not name it.

    Returns
    -------
    dict of str to pathlib.Path
        ``{format: path}`` in the order written.

    Raises
    ------
    ConfigValueError
        An unknown format.
    OutputFormatError, TruthSchemaError
        Data the format cannot hold.

    Examples
    --------
    Any object with the four fields will do (here a 12-bit image; the PNG's bit depth comes
    from the truth's camera):

    >>> import tempfile
    >>> from types import SimpleNamespace
    >>> from skynav.datasets import write_frame
    >>> from skynav.datasets.frame_files import read_png
    >>> frame = SimpleNamespace(dn=np.array([[0, 4095]], dtype=np.uint16),
    ...                         electrons=np.zeros((1, 2), np.float32),
    ...                         irradiance_w_m2=np.zeros((1, 2), np.float32),
    ...                         truth={"camera": {"bit_depth": 12}})
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     paths = write_frame(frame, tmp, "frame", formats=("png", "exr"))
    ...     print(sorted(paths), read_png(paths["png"]).tolist())
    ['exr', 'png'] [[0, 4095]]
    """
    check_stem(stem)
    directory = Path(directory)
    if not directory.is_dir():  # an existing folder (a dataset's frames/) needs no more checks per frame
        check_output_dir(directory)
        try:
            directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputPathError(f"{directory}: cannot create the output folder "
                                  f"({exc.strerror or exc.__class__.__name__})") from None
    # encode everything first: an unknown format or bad data writes nothing
    blobs = {fmt: (directory / f"{stem}.{fmt}", data) for fmt, data in encode_frame(frame, formats, fits=fits).items()}
    write_files(blobs.values())
    return {fmt: path for fmt, (path, _) in blobs.items()}


def encode_frame(frame, formats=("png", "exr", "json"), *, fits: bool = False) -> dict:
    """``{format: bytes}``: the files :func:`write_frame` writes for a frame, in memory (the
    dataset runner encodes a frame, then writes it on another thread while it renders the next).
    Raises what :func:`write_frame` raises for an unknown format or data a format cannot hold."""
    blobs = {}
    for fmt in tuple(formats) + (("fits",) if fits and "fits" not in formats else ()):
        if fmt in ("png", "exr", "json"):
            blobs[fmt] = frame_file_bytes(frame, fmt)
        elif fmt == "fits":
            t = frame.truth
            hdr = sky_wcs_header(Camera.from_dict(dict(t["camera"])), np.array(t["attitude"]["R_cam_icrs"]))
            blobs[fmt] = fits_bytes(frame.dn, hdr, fits_frame_header(t))
        else:
            raise ConfigValueError("formats", fmt, "png, exr, json or fits")
    return blobs


def write_files(files) -> None:
    """Write ``(path, bytes)`` pairs, each atomically (temp file, fsync, rename, folder fsync)
    on its own thread: the fsyncs wait on the disk with the GIL released, so they overlap even
    on one core (what :func:`write_frame` does with a frame's encoded files)."""
    files = list(files)
    if len(files) > 1:
        with ThreadPoolExecutor(len(files), thread_name_prefix="skynav-write") as pool:
            for job in [pool.submit(atomic_write_bytes, path, data) for path, data in files]:
                job.result()
    else:
        for path, data in files:
            atomic_write_bytes(path, data)


def frame_file_bytes(frame, fmt: str) -> bytes:
    """The bytes :func:`write_frame` writes for one format of a frame (``png``, ``exr`` or ``json``).

    One encoder for the files and for programs that take frames in memory (the render service
    answers with these bytes, so they equal the files of ``skynav render``).
    """
    if fmt == "png":
        return png_bytes(frame.dn, bit_depth=frame.truth["camera"]["bit_depth"])
    if fmt == "exr":
        return exr_bytes({"electrons": frame.electrons, "irradiance_w_m2": frame.irradiance_w_m2})
    if fmt == "json":
        return truth_json_bytes(frame.truth)
    raise ConfigValueError("formats", fmt, "png, exr or json")
