"""numpy's runtime CPU dispatch, for .ci/run.

    python3 .ci/numpy_cpu_features.py optional
        print the dispatch targets this numpy build has beyond its baseline AND this CPU
        supports (space separated; empty if none): the value for NPY_DISABLE_CPU_FEATURES.
        The baseline is compiled in and cannot be disabled (numpy raises if asked to).
    python3 .ci/numpy_cpu_features.py check FEATURE ...
        print numpy's version, baseline, dispatch targets and the features enabled now, and
        exit 1 if any FEATURE is still enabled (i.e. NPY_DISABLE_CPU_FEATURES did not take).

numpy >= 2 keeps the tables in ``numpy._core._multiarray_umath``, numpy 1.x in
``numpy.core._multiarray_umath``. See numpy's "CPU build options" / runtime dispatch docs.
"""

import sys

import numpy

try:
    from numpy._core import _multiarray_umath as _mu
except ImportError:  # numpy 1.x
    from numpy.core import _multiarray_umath as _mu


def optional():
    feats = _mu.__cpu_features__
    return [f for f in _mu.__cpu_dispatch__ if feats.get(f)]


def main(argv):
    if argv[:1] == ["optional"]:
        print(" ".join(optional()))
        return 0
    if argv[:1] == ["check"]:
        feats = _mu.__cpu_features__
        print(f"numpy {numpy.__version__}: baseline {' '.join(_mu.__cpu_baseline__)}; "
              f"dispatch targets {' '.join(_mu.__cpu_dispatch__)}")
        print(f"  dispatch targets enabled now: {' '.join(optional()) or '(none: the baseline path)'}")
        still = [f for f in argv[1:] if feats.get(f)]
        if still:
            print(f"  NOT disabled: {' '.join(still)}", file=sys.stderr)
            return 1
        return 0
    print(__doc__, file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
