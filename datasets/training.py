"""Frames for training: a recipe's frames in batches, in memory, with their labels.

Driver module. :func:`stream` renders the frames of a recipe (a file, a preset name or the
mapping ``skynav dataset generate`` takes) and yields one mapping per batch of ``batch``
consecutive frames: the image stack, the labels a network learns from (:data:`LABELS`) and
the full ground truth, with no file written. Frame k is made by
:func:`skynav.datasets.execute.render_request`, the function that makes a dataset's frame k, from
``SeedSequence([seed, k])`` alone: a streamed frame is the dataset's frame of the same seed and
index (truth and expected image), whatever the batch size, the shard or the worker that made it.

The arrays are numpy arrays (``device="cpu"``) or Dr.Jit tensors (``"llvm"``, ``"cuda"``); both
export the DLPack protocol, so ``torch.from_dlpack`` and ``jax.numpy.from_dlpack`` take them
without a copy. :func:`torch_dataset` (a PyTorch ``IterableDataset`` that splits the batches over
the ``DataLoader``'s workers) and :func:`jax_batches` are the thin adapters (the ``ml`` extra).
"""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Iterator, Mapping

import numpy as np

from skynav.renderer import jit_backend
from skynav.renderer.batch import render_batch
from skynav.renderer.options import RenderOptions
from skynav.renderer.sensor_jit import _jit_module

from .errors import DatasetError
from .execute import dataset_truth, frame_scene, render_request
from .labels import LABELS, collate
from .recipe_checks import validate_recipe
from .recipes import read_recipe_mapping
from .runner import recipe_render_options
from .samplers import make_plan
from .truth_schema import truth_to_jsonable

__all__ = ["LABELS", "DEVICES", "stream", "torch_dataset", "jax_batches"]

DEVICES = ("cpu", "llvm", "cuda")


def _to_device(batch: dict, device: str) -> dict:
    """The batch's arrays as Dr.Jit tensors of ``device`` (``"llvm"``, ``"cuda"``); ``"cpu"``: as is."""
    if device == "cpu":
        return batch
    jt = _jit_module(device)
    tensors = {np.dtype(np.uint8): jt.TensorXu8, np.dtype(np.uint16): jt.TensorXu, np.dtype(np.int64): jt.TensorXi64,
               np.dtype(np.float32): jt.TensorXf, np.dtype(np.float64): jt.TensorXf64, np.dtype(bool): jt.TensorXb}
    out = {}
    for key, v in batch.items():
        if isinstance(v, np.ndarray):
            v = tensors[v.dtype](v.astype(np.uint32) if v.dtype == np.uint16 else v)
        out[key] = v
    return out


def _check_device(device: str, options):
    """The render options of ``device`` (its sensor backend), or one line naming what is allowed."""
    if device not in DEVICES:
        raise DatasetError(f"device = {device!r} is not allowed; expected one of: {', '.join(DEVICES)}")
    if device == "cpu":
        return options
    jit_backend.require(device)  # one line (BackendUnavailableError) if it does not work here
    return dataclasses.replace(options, backend=device)


def _recipe_mapping(recipe) -> dict:
    if isinstance(recipe, Mapping):
        return validate_recipe(dict(recipe))
    if isinstance(recipe, (str, os.PathLike)):
        return validate_recipe(read_recipe_mapping(os.fspath(recipe)))
    raise DatasetError(f"recipe = {type(recipe).__name__} is not allowed; expected a recipe file, a preset name "
                       "or a recipe mapping")


def _check_counts(batch, start, stop, shard, n_frames):
    if not (isinstance(batch, (int, np.integer)) and not isinstance(batch, bool) and batch >= 1):
        raise DatasetError(f"batch = {batch!r} is not allowed; expected an integer >= 1")
    stop = n_frames if stop is None else stop
    if not (0 <= start <= stop <= n_frames):
        raise DatasetError(f"frames {start}..{stop} are not allowed; expected 0 <= start <= stop <= {n_frames} "
                           "(the recipe's frames)")
    index, count = shard
    if not (0 <= index < count):
        raise DatasetError(f"shard = {shard!r} is not allowed; expected (i, n) with 0 <= i < n")
    return stop


def stream(recipe, *, batch: int = 1, device: str = "cpu", electrons: bool = False, start: int = 0,
           stop: int | None = None, shard: tuple = (0, 1), render_options=None, ephemeris=None) -> Iterator[dict]:
    """Yield the recipe's frames in batches, in memory, with their labels.

    Parameters
    ----------
    recipe : str, os.PathLike or mapping
        A recipe file, a preset name (``montecarlo``, ``sequence``, ``scenes``), or a recipe
        mapping, as :func:`skynav.datasets.generate` takes.
    batch : int
        Frames per batch; the last batch holds what is left.
    device : {"cpu", "llvm", "cuda"}
        ``"cpu"``: the dataset's per-frame path, numpy arrays, the sensor on
        ``render_options.backend`` (default ``auto``): frame k is the dataset's frame k to the
        bit. ``"llvm"``, ``"cuda"``: the batched frame program
        (:func:`skynav.renderer.batch.render_batch`: the same expected images, electrons and
        truth, the sensor chain of the batch as one launch on that backend, its DN the same
        statistics) and the arrays as that backend's tensors, the DN never copied to the host.
    electrons : bool
        Add ``electrons``, the float32 expected electrons with the cosmic-ray charge.
    start, stop : int
        The frames ``start .. stop - 1`` (default: all the recipe's).
    shard : (int, int)
        ``(i, n)``: only batches ``b`` with ``b % n == i`` (batch ``b`` holds frames
        ``start + b * batch ..``): how ``n`` workers share a stream.
    render_options : RenderOptions, optional
        As :func:`~skynav.datasets.generate`'s; the recipe's ``render:`` keys win.
    ephemeris : optional
        As :func:`~skynav.datasets.generate`'s.

    Yields
    ------
    dict
        One mapping per batch, keys and shapes in :data:`LABELS`.

    Raises
    ------
    DatasetError, RecipeError
        A bad argument or recipe (one line naming it).

    Examples
    --------
    >>> from skynav.datasets import preset_recipe, stream
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe.update(frames=3, camera={"preset": "paper", "width": 64, "height": 64, "fov_deg": 20})
    >>> batches = list(stream(recipe, batch=2, electrons=True))
    >>> [b["image"].shape for b in batches], batches[0]["electrons"].dtype.name
    ([(2, 64, 64), (1, 64, 64)], 'float32')
    >>> batches[1]["frame"].tolist(), batches[0]["q_cam_icrs"].shape
    ([2], (2, 4))
    """
    recipe = _recipe_mapping(recipe)
    options = recipe_render_options(recipe, render_options if render_options is not None else RenderOptions())
    options = _check_device(device, options)
    plan = make_plan(recipe, ephemeris=ephemeris)
    stop = _check_counts(batch, start, stop, tuple(shard), plan.n_frames)
    seed, mag = int(recipe["seed"]), float(recipe["catalog_limiting_v_mag"])
    index, count = shard
    for b, first in enumerate(range(start, stop, batch)):
        if b % count != index:
            continue
        ks = list(range(first, min(first + batch, stop)))
        if device == "cpu":
            frames = []
            for k in ks:
                frame, _, _ = render_request(plan, k, master_seed=seed, catalog_limiting_v_mag=mag, render_options=options)
                frames.append({"dn": frame.dn, "electrons": frame.electrons if electrons else None,
                               "truth": truth_to_jsonable(frame.truth)})
            yield collate(frames, ks)
        else:
            yield _to_device(_device_batch(plan, ks, seed, mag, options, electrons, device), device)


def _device_batch(plan, ks, seed: int, mag: float, options, electrons: bool, device: str) -> dict:
    """The frames ``ks`` by the batched frame program (:func:`skynav.renderer.batch.render_batch`):
    the optics per frame as the dataset's, the sensor chain of the batch as one launch on
    ``device``, the DN left there as a tensor."""
    drawn = [frame_scene(plan, k, master_seed=seed, catalog_limiting_v_mag=mag, render_options=options) for k in ks]
    opts = drawn[0][1]
    if any(d[1] != opts for d in drawn):  # a scenes recipe's own render keys differ between frames
        raise DatasetError(f"frames {ks[0]}..{ks[-1]} have different render options (a scenes recipe's own render "
                           f"keys); stream them with device='cpu' or batch=1")
    out = render_batch([d[0] for d in drawn], [d[2] for d in drawn], rngs=[d[3] for d in drawn], options=opts,
                       frames_per_launch=len(ks), electrons=electrons)
    jt = _jit_module(device)
    n, h, w = out.shape
    tensor = jt.TensorXu8 if out.dtype == np.uint8 else jt.TensorXu
    image = tensor(out.dn_device[0], shape=(n, h, w))
    frames = [{"dn": None, "electrons": out.electrons[i] if electrons else None,
               "truth": truth_to_jsonable(dataset_truth(out.truths[i], d[4], seed))} for i, d in enumerate(drawn)]
    return collate(frames, ks, image=image)


def _dlpack_tensors(batch: dict, from_dlpack) -> dict:
    """The batch with every array exchanged through DLPack (no copy); other values as they are."""
    return {k: from_dlpack(v) if hasattr(v, "__dlpack__") else v for k, v in batch.items()}


def torch_dataset(recipe, **kwargs):
    """A PyTorch ``IterableDataset`` of :func:`stream`'s batches (tensors through DLPack).

    Use it with ``torch.utils.data.DataLoader(ds, batch_size=None, num_workers=n,
    multiprocessing_context="spawn")``: worker ``i`` of ``n`` renders batches ``i, i + n, ...``
    (``shard=(i, n)``), so every batch is made once and frame k is the same whatever ``n``
    (spawn: Dr.Jit keeps threads that a forked worker must not inherit).

    Parameters
    ----------
    recipe : str, os.PathLike or mapping
        As :func:`stream`.
    **kwargs
        :func:`stream`'s other arguments (not ``shard``).

    Returns
    -------
    torch.utils.data.IterableDataset
        Its items are :func:`stream`'s batches, arrays as ``torch.Tensor``.

    Raises
    ------
    DatasetError
        PyTorch is not installed (the ``ml`` extra).

    Examples
    --------
    >>> from skynav.datasets import DatasetError, preset_recipe, torch_dataset
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe.update(frames=2, camera={"preset": "paper", "width": 64, "height": 64, "fov_deg": 20})
    >>> try:
    ...     batch = next(iter(torch_dataset(recipe, batch=2)))
    ...     print(type(batch["image"]).__name__, tuple(batch["image"].shape))
    ... except DatasetError:   # without PyTorch
    ...     print("Tensor", (2, 64, 64))
    Tensor (2, 64, 64)
    """
    return _frame_stream_class()(recipe, kwargs)


@functools.lru_cache(maxsize=1)
def _frame_stream_class():
    """The ``IterableDataset`` class of :func:`torch_dataset`, made on first use (PyTorch is
    optional); the module's ``FrameStream`` (:func:`__getattr__`), so that a spawned
    ``DataLoader`` worker unpickles it by name."""
    try:
        # PyTorch: the optional 'ml' extra, only for this adapter
        import torch
        from torch.utils.data import IterableDataset, get_worker_info
    except ImportError:
        raise DatasetError("torch_dataset needs PyTorch: pip install 'skynav[ml]'") from None

    class FrameStream(IterableDataset):
        """The batches of a recipe, split over the DataLoader's workers."""

        def __init__(self, recipe, kwargs):
            super().__init__()
            self.recipe, self.kwargs = recipe, dict(kwargs)

        def __iter__(self):
            info = get_worker_info()
            shard = (0, 1) if info is None else (info.id, info.num_workers)
            for batch in stream(self.recipe, shard=shard, **self.kwargs):
                yield _dlpack_tensors(batch, torch.from_dlpack)

    FrameStream.__module__, FrameStream.__qualname__ = __name__, "FrameStream"
    return FrameStream


def __getattr__(name):
    if name == "FrameStream":  # a DataLoader worker unpickling a torch_dataset
        return _frame_stream_class()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def jax_batches(recipe, **kwargs) -> Iterator[dict]:
    """:func:`stream`'s batches as JAX arrays (``jax.numpy.from_dlpack``).

    JAX rounds the float64 labels to float32 unless ``jax.config.update("jax_enable_x64", True)``.

    Parameters
    ----------
    recipe : str, os.PathLike or mapping
        As :func:`stream`.
    **kwargs
        :func:`stream`'s other arguments.

    Returns
    -------
    iterator of dict
        :func:`stream`'s batches, arrays as ``jax.Array``.

    Raises
    ------
    DatasetError
        JAX is not installed (the ``ml`` extra).

    Examples
    --------
    >>> from skynav.datasets import DatasetError, jax_batches, preset_recipe
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe.update(frames=2, camera={"preset": "paper", "width": 64, "height": 64, "fov_deg": 20})
    >>> try:
    ...     batch = next(jax_batches(recipe, batch=2))
    ...     print(tuple(batch["image"].shape), batch["star_xy"].shape[-1])
    ... except DatasetError:   # without JAX
    ...     print((2, 64, 64), 2)
    (2, 64, 64) 2
    """
    try:
        # JAX: the optional 'ml' extra, only for this adapter
        import jax.numpy as jnp
    except ImportError:
        raise DatasetError("jax_batches needs JAX: pip install 'skynav[ml]'") from None
    for batch in stream(recipe, **kwargs):
        yield _dlpack_tensors(batch, jnp.from_dlpack)
