"""The on-board star catalog and its inter-star-angle k-vector (Andreis et al. (2023a), Sec. III.A.2).

Adapter: built once from Hipparcos (:mod:`skynav.scenes.catalog_hipparcos`), stars with
``V < limiting_v_mag`` (5.5 by default) and every pair closer than ``max_angle_rad`` (the field's
diagonal), sorted by angle with the pair ids ``I``, ``J``; cached as one ``.npz`` in
:func:`skynav.infra.data_files.cache_dir`, keyed by the build parameters.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from skynav.infra.data_files import cache_dir, hip2_path
from skynav.scenes.catalog_hipparcos import load_catalog

from .kvector import KVector

__all__ = ["OnboardCatalog"]

CACHE_VERSION = 1


@dataclass(frozen=True, kw_only=True, eq=False)
class OnboardCatalog:
    """Stars and star pairs the spacecraft carries.

    Attributes
    ----------
    stars : skynav.scenes.catalog_hipparcos.StarCatalog
        The catalog stars (V < limiting_v_mag), for epoch propagation of matched stars.
    u_icrs : ndarray, shape (N, 3)
        Unit vectors at the catalog epoch.
    v_mag : ndarray, shape (N,)
    hip : ndarray of int, shape (N,)
    pair_i, pair_j : ndarray of int32, shape (P,)
        Star indices of each pair, in the order of :attr:`kvector` values (angles, rad).
    kvector : KVector
        Over the sorted inter-star angles, rad.
    limiting_v_mag, max_angle_rad : float
        Build parameters.
    build_time_s : float
        Wall time of the build (pairs + sort + k-vector), s; 0 when loaded from the cache.
    deep_cache : dict
        The deeper catalogues of :meth:`deep_stars`, by magnitude limit (filled on use).

    References
    ----------
    Andreis et al. (2023a), Sec. III.A.2 (the k-vector of inter-star angles); Mortari, D. &
    Neta, B. (2000), "k-vector range searching techniques", AAS 00-128.

    Examples
    --------
    >>> from skynav.pipeline import OnboardCatalog
    >>> from skynav.scenes import paper_camera
    >>> cat = OnboardCatalog.load(camera=paper_camera())   # built and cached on first use
    >>> cat
    OnboardCatalog(<2867 stars V<5.5, 265116 pairs < 28.00 deg>)
    >>> bool(np.all(np.diff(cat.kvector.values) >= 0))   # pair angles, sorted, rad
    True
    """

    stars: object
    u_icrs: np.ndarray
    v_mag: np.ndarray
    hip: np.ndarray
    pair_i: np.ndarray
    pair_j: np.ndarray
    kvector: KVector
    limiting_v_mag: float
    max_angle_rad: float
    build_time_s: float = 0.0
    # the deep catalogs of deep_stars, by magnitude limit: loaded once, owned by this object
    deep_cache: dict = field(default_factory=dict, repr=False)

    def __repr__(self) -> str:
        return (f"OnboardCatalog(<{len(self.hip)} stars V<{self.limiting_v_mag:g}, {len(self.pair_i)} pairs "
                f"< {np.degrees(self.max_angle_rad):.2f} deg>)")

    # ------------------------------------------------------------------ build / cache
    @classmethod
    def build(cls, *, limiting_v_mag: float = 5.5, max_angle_rad: float | None = None, camera=None,
              star_catalog=None) -> "OnboardCatalog":
        """Build from Hipparcos (no cache).

        Parameters
        ----------
        limiting_v_mag : float
            Keep stars with ``V < limiting_v_mag``.
        max_angle_rad : float, optional
            Largest pair angle; default: the diagonal field of ``camera`` (2 x half-diagonal),
            else 30 deg.
        camera : skynav.scenes.camera.Camera, optional
            The camera whose field sets the largest pair angle.
        star_catalog : StarCatalog, optional
            Source catalog (default: the installed Hipparcos).

        Returns
        -------
        OnboardCatalog
            The stars, their pairs sorted by angle (rad) and the k-vector.
        """
        if max_angle_rad is None:
            max_angle_rad = 2.0 * camera.half_diagonal_fov_rad if camera is not None else np.radians(30.0)
        t0 = time.perf_counter()
        full = star_catalog if star_catalog is not None else load_catalog()
        idx = np.flatnonzero(full.v_mag < limiting_v_mag)
        stars = full.subset(idx)
        u = np.asarray(stars.u_icrs, dtype=float)
        tree = cKDTree(u)
        chord = 2.0 * np.sin(0.5 * max_angle_rad)
        pairs = tree.query_pairs(chord, output_type="ndarray")
        pi, pj = pairs[:, 0].astype(np.int32), pairs[:, 1].astype(np.int32)
        ang = np.arccos(np.clip(np.einsum("ij,ij->i", u[pi], u[pj]), -1.0, 1.0))
        order = np.argsort(ang, kind="stable")
        kv = KVector.build(ang[order])
        build_s = time.perf_counter() - t0
        return cls(stars=stars, u_icrs=u, v_mag=np.asarray(stars.v_mag, float), hip=np.asarray(stars.hip),
                   pair_i=pi[order], pair_j=pj[order], kvector=kv, limiting_v_mag=float(limiting_v_mag),
                   max_angle_rad=float(max_angle_rad), build_time_s=build_s)

    @staticmethod
    def cache_file(*, limiting_v_mag: float = 5.5, max_angle_rad: float) -> Path:
        """Path of the cached catalogue built with these parameters (``.npz`` in the cache folder)."""
        key = f"{CACHE_VERSION}|{limiting_v_mag!r}|{max_angle_rad!r}|{hip2_path()}"
        return cache_dir() / f"onboard_kvector_{hashlib.sha256(key.encode()).hexdigest()[:16]}.npz"

    @classmethod
    def load(cls, *, limiting_v_mag: float = 5.5, max_angle_rad: float | None = None, camera=None,
             use_cache: bool = True) -> "OnboardCatalog":
        """The catalog from the disk cache, building (and caching) it on first use.

        Parameters
        ----------
        limiting_v_mag : float
            Keep stars with ``V < limiting_v_mag``.
        max_angle_rad : float, optional
            Largest pair angle, rad; default: the diagonal field of ``camera``, else 30 deg.
        camera : skynav.scenes.camera.Camera, optional
            The camera whose field sets the largest pair angle.
        use_cache : bool
            Read and write the cache (False: build, cache nothing).

        Returns
        -------
        OnboardCatalog
            The same catalogue as :meth:`build` (a stale or broken cache file is rebuilt).
        """
        if max_angle_rad is None:
            max_angle_rad = 2.0 * camera.half_diagonal_fov_rad if camera is not None else np.radians(30.0)
        max_angle_rad = float(max_angle_rad)
        path = cls.cache_file(limiting_v_mag=limiting_v_mag, max_angle_rad=max_angle_rad)
        if use_cache and path.exists():
            try:
                with np.load(path) as z:
                    full = load_catalog()
                    idx = z["source_index"]
                    stars = full.subset(idx)
                    kv = KVector(values=z["values"], k=z["k"], a0=float(z["a0"]), a1=float(z["a1"]))
                    return cls(stars=stars, u_icrs=np.asarray(stars.u_icrs, float), v_mag=np.asarray(stars.v_mag, float),
                               hip=np.asarray(stars.hip), pair_i=z["pair_i"], pair_j=z["pair_j"], kvector=kv,
                               limiting_v_mag=float(limiting_v_mag), max_angle_rad=max_angle_rad)
            except (OSError, KeyError, ValueError):
                pass  # a stale or broken cache file is rebuilt
        cat = cls.build(limiting_v_mag=limiting_v_mag, max_angle_rad=max_angle_rad)
        if use_cache:
            full = load_catalog()
            source_index = np.flatnonzero(full.v_mag < limiting_v_mag)
            fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".npz.tmp")
            try:
                with os.fdopen(fd, "wb") as f:
                    np.savez(f, source_index=source_index, values=cat.kvector.values, k=cat.kvector.k,
                             a0=cat.kvector.a0, a1=cat.kvector.a1, pair_i=cat.pair_i, pair_j=cat.pair_j)
                os.replace(tmp, path)
            finally:
                if os.path.exists(tmp):
                    os.unlink(tmp)
        return cat

    def deep_stars(self, deep_v_mag: float = 9.0):
        """The full Hipparcos catalog to ``deep_v_mag`` (loaded once, cached on the object).

        The improved beacon mode uses it to tell faint stars from beacons.

        Parameters
        ----------
        deep_v_mag : float
            Keep the stars with ``V < deep_v_mag``, mag.

        Returns
        -------
        skynav.scenes.catalog_hipparcos.StarCatalog
            The stars, at the catalogue epoch.
        """
        cache = self.deep_cache
        if deep_v_mag not in cache:
            full = load_catalog()
            cache[deep_v_mag] = full.subset(np.flatnonzero(full.v_mag < deep_v_mag))
        return cache[deep_v_mag]

    # ------------------------------------------------------------------ queries
    def pairs_in_range(self, lo_rad: float, hi_rad: float):
        """Star indices of every pair whose angle is in ``[lo_rad, hi_rad]`` (a k-vector search).

        Parameters
        ----------
        lo_rad, hi_rad : float
            The angle range, rad.

        Returns
        -------
        I, J : numpy.ndarray of int32
            Indices into :attr:`u_icrs` of the pairs' two stars.

        References
        ----------
        Andreis et al. (2023a), Sec. III.A.2.
        """
        s = self.kvector.range(lo_rad, hi_rad)
        return self.pair_i[s], self.pair_j[s]
