"""Guard: no test asks two implementations for identical bits.

numpy's SIMD loops (``log10``, ``arctan2``, ``exp`` ...) differ from libm's in the last bit on
some CPUs, BLAS kernels differ by CPU, and Dr.Jit compiles for the machine it runs on: a test
that asks a scalar twin, a second library or a compiled kernel for numpy's exact bits passes on
one machine and fails on another. Two implementations are compared within a tolerance in ulps
or physical units, with the reason. Identical bits remain a fair demand of
*determinism*: the same code run twice with the same seed, a file written and read back.

The rule, applied to every ``tests/**/*.py`` (this file excepted):

    Cut a test file into its top-level statements (a function or class with its decorators and
    the comments above it; the module docstring alone). A piece that says it checks identical
    bits, i.e. contains one of :data:`BIT_PHRASES` (any case, ``_`` read as a space, so test
    names count), must also say why bits may be identical there, i.e. contain one of
    :data:`DETERMINISM_MARKERS`: the same code, the same seed, or a round trip through a file.

So a test may keep ``bit_identical`` in its name or "same bits" in its docstring only next to
the words that make it a determinism test; anything else must be rewritten to a tolerance.
``.ci/run`` backs this up by running the suite again with numpy's optional CPU features off
(NPY_DISABLE_CPU_FEATURES), which catches an exact comparison that no phrase announces.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

TESTS = Path(__file__).resolve().parent

BIT_PHRASES = ("bit identical", "bit for bit", "bit-identical", "bit-for-bit", "identical bits", "same bits",
               "to the bit", "byte identical", "byte-identical", "bitwise identical", "bitwise equal")
DETERMINISM_MARKERS = ("same code", "same seed", "round trip", "round-trip", "read back")


def _norm(text: str) -> str:
    return re.sub(r"\s+", " ", text.replace("_", " ")).lower()


def offending_pieces(source: str) -> list[tuple[int, str]]:
    """``(first line, phrase)`` of each top-level piece of ``source`` that claims identical bits
    without a determinism marker (the rule in the module docstring)."""
    tree = ast.parse(source)
    lines = source.splitlines()
    out, start = [], 1
    for node in tree.body:
        first = min([node.lineno] + [d.lineno for d in getattr(node, "decorator_list", [])])
        piece = _norm("\n".join(lines[start - 1:node.end_lineno]))
        hits = [p for p in BIT_PHRASES if p in piece]
        if hits and not any(m in piece for m in DETERMINISM_MARKERS):
            out.append((first, hits[0]))
        start = node.end_lineno + 1
    tail = _norm("\n".join(lines[start - 1:]))  # trailing comments
    hits = [p for p in BIT_PHRASES if p in tail]
    if hits and not any(m in tail for m in DETERMINISM_MARKERS):
        out.append((start, hits[0]))
    return out


def test_no_test_asks_two_implementations_for_identical_bits():
    bad = []
    for path in sorted(TESTS.rglob("*.py")):
        if path.resolve() == Path(__file__).resolve():
            continue
        for line, phrase in offending_pieces(path.read_text(encoding="utf-8")):
            bad.append(f"{path.relative_to(TESTS.parent)}:{line}: says {phrase!r} without a determinism marker")
    assert not bad, ("tests that claim identical bits must be determinism tests (same code, same seed, "
                     "round trip / read back); compare two implementations within ulps instead:\n" + "\n".join(bad))


# ----------------------------------------------------------------------------- the guard itself
_BAD = '''
import numpy as np


def test_twin_bit_identical_to_numpy():
    """Reference: numpy.log10."""
    assert twin(x) == float(np.log10(x))


def test_fast_path():
    # the fast path gives the same bits as the reference
    assert fast(x) == slow(x)
'''

_GOOD = '''
"""Module docstring without any claim."""


def test_same_seed_same_bits():
    assert np.array_equal(render(seed=1), render(seed=1))


def test_file_round_trip():
    # written and read back: bit for bit
    assert read(write(a)) == a


def test_twin_agrees_within_4_ulps():
    np.testing.assert_array_max_ulp(twin(x), np.log10(x), maxulp=4)
'''


def test_guard_flags_a_twin_compared_bit_for_bit():
    """A deliberately bad source: a twin against numpy named ``bit_identical`` and a fast path
    said to give "the same bits" are both flagged, at their first lines."""
    assert offending_pieces(_BAD) == [(5, "bit identical"), (10, "same bits")]


def test_guard_accepts_determinism_and_tolerances():
    assert offending_pieces(_GOOD) == []


def test_guard_reads_decorators_comments_and_the_module_docstring():
    src = ('"""Everything here is bit-for-bit."""\n\n# the same bits below\n@pytest.mark.parametrize("a", [1])\n'
           'def test_x(a):\n    pass\n')
    assert offending_pieces(src) == [(1, "bit-for-bit"), (4, "same bits")]
    assert offending_pieces(src.replace("Everything here", "Same seed: everything")) == [(4, "same bits")]
