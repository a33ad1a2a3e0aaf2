"""Hipparcos catalog speed: cold parse, cached load, cone queries for a 20 deg field.

Run: ``python benchmarks/catalog_bench.py``. Uses a temporary cache directory so the "cold"
figure really parses ``hip2.dat`` (and writes the cache), and the "cached" figure really reads
the ``.npz`` (in-process memo cleared).
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time

import numpy as np


def _median_s(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["SKYNAV_CACHE_DIR"] = tmp
        from skynav.scenes import catalog_hipparcos as ch

        t0 = time.perf_counter()
        cat = ch.load_catalog()  # parse + write the cache
        cold_s = time.perf_counter() - t0

        def cached():
            ch._MEMO.clear()
            ch.load_catalog()

        cached_s = _median_s(cached, 7)
        memo_s = _median_s(ch.load_catalog, 100)
        with open(ch.hip2_path(), "rb") as f:
            t0 = time.perf_counter()
            ch.read_hipparcos(f)
            parse_s = time.perf_counter() - t0

        print(f"stars: {len(cat)}")
        print(f"cold load (parse + write cache): {cold_s * 1e3:8.1f} ms")
        print(f"read_hipparcos (parse only):     {parse_s * 1e3:8.1f} ms")
        print(f"cached load (.npz):              {cached_s * 1e3:8.1f} ms  (limit 500 ms)")
        print(f"memoised load:                   {memo_s * 1e6:8.1f} us")

        rng = np.random.default_rng(0)
        centres = rng.normal(size=(500, 3))
        radius = np.radians(14.1)  # half-diagonal of a 20 deg x 20 deg field
        for label, vmax in (("V <= 9", 9.0), ("all magnitudes", None)):
            it = iter(np.tile(centres, (4, 1)))
            counts = [cat.cone(c, radius, limiting_v_mag=vmax).size for c in centres]
            t = _median_s(lambda: cat.cone(next(it), radius, limiting_v_mag=vmax), 2000)
            print(f"cone r=14.1 deg, {label:15s}: median {t * 1e6:7.1f} us over 2000 random "
                  f"centres (limit 5 ms), median {int(np.median(counts))} stars returned")
        for label, c in (("north pole", [0, 0, 1.0]), ("equator", [1.0, 0, 0])):
            t = _median_s(lambda: cat.cone(c, radius), 500)
            print(f"cone r=14.1 deg, all mags, {label:10s}: median {t * 1e6:7.1f} us")


if __name__ == "__main__":
    main()
