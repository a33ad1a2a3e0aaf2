"""Mortari's k-vector range search (Mortari 1997; Mortari & Neta 2000; Andreis et al. (2023a), Sec. III.A.2).

Core module. For a sorted array ``S`` of n values, the straight line ``z(k) = a1 k + a0`` joins
``(0, S[0] - d)`` and ``(n - 1, S[n-1] + d)``; ``K[k]`` is the number of elements of ``S`` that are
``<= z(k)``. A query ``[ya, yb]`` maps to the indices ``jb = floor((ya - a0) / a1)`` and
``jt = ceil((yb - a0) / a1)`` with no search, and ``S[K[jb] : K[jt]]`` holds every element in the
range plus at most a few at both ends, trimmed here so the result is exact.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["KVector"]


@dataclass(frozen=True, kw_only=True, eq=False)
class KVector:
    """A k-vector over sorted values.

    Attributes
    ----------
    values : ndarray, shape (n,)
        Sorted values ``S``.
    k : ndarray of int64, shape (n,)
        ``K[k] = #{S <= a1 k + a0}``.
    a0, a1 : float
        The line's coefficients.
    """

    values: np.ndarray
    k: np.ndarray
    a0: float
    a1: float

    @classmethod
    def build(cls, sorted_values) -> "KVector":
        s = np.asarray(sorted_values, dtype=float)
        n = len(s)
        if n < 2:
            raise ValueError("a k-vector needs at least two values")
        if np.any(np.diff(s) < 0):
            raise ValueError("k-vector values must be sorted ascending")
        d = np.finfo(float).eps * max(abs(s[0]), abs(s[-1]), 1.0) * (n - 1)
        a1 = (s[-1] - s[0] + 2 * d) / (n - 1)
        a0 = s[0] - d
        z = a1 * np.arange(n) + a0
        k = np.searchsorted(s, z, side="right").astype(np.int64)
        return cls(values=s, k=k, a0=float(a0), a1=float(a1))

    def range(self, lo: float, hi: float) -> slice:
        """Slice of :attr:`values` with exactly the elements in ``[lo, hi]``."""
        n = len(self.values)
        if hi < lo or hi < self.values[0] or lo > self.values[-1]:
            return slice(0, 0)
        jb = int(np.floor((lo - self.a0) / self.a1))
        jt = int(np.ceil((hi - self.a0) / self.a1))
        start = int(self.k[jb]) if jb >= 0 else 0
        end = int(self.k[jt]) if jt < n else n
        start = max(start - 1, 0)
        # trim the few extra elements at both ends (the k-vector's superset)
        v = self.values
        while start < end and v[start] < lo:
            start += 1
        while end > start and v[end - 1] > hi:
            end -= 1
        return slice(start, end)

    def ranges(self, lo, hi):
        """Vectorised :meth:`range`: (start, end) int arrays for arrays of bounds."""
        lo = np.asarray(lo, dtype=float)
        hi = np.asarray(hi, dtype=float)
        # the k-vector gives a bracket; searchsorted within it is the same as the exact trim
        n = len(self.values)
        jb = np.clip(np.floor((lo - self.a0) / self.a1).astype(np.int64), -1, n - 1)
        jt = np.clip(np.ceil((hi - self.a0) / self.a1).astype(np.int64), 0, n)
        start = np.where(jb >= 0, self.k[np.maximum(jb, 0)], 0)
        end = np.where(jt < n, self.k[np.minimum(jt, n - 1)], n)
        start = np.maximum(start - 1, 0)
        # exact trim (the bracket is a handful of elements wider than the answer)
        start = np.searchsorted(self.values, lo, side="left").clip(start, None)
        end = np.minimum(np.searchsorted(self.values, hi, side="right"), end)
        return start, np.maximum(end, start)
