"""Every documented command and example runs, as a user types it (the docs test).

What runs
---------
Every fenced ``bash`` block of README.md and docs/*.md runs through ``bash`` (``set -e -o
pipefail``: the first failing command fails the block, named by its line in the document), and
every ``python`` block is saved as a script file and run with ``python FILE`` (so an example that
only works pasted into an interpreter, e.g. one that starts worker processes without an
``if __name__ == "__main__":`` guard, fails here as it would for a user).

Where: one temporary folder per document, the blocks in document order, so that commands that
build on each other (the README tour: generate ``mc``, then ``dataset verify mc``, ``bench ip mc``)
see each other's files. The folder holds a copy of the checkout's ``docs/examples/`` and
``benchmarks/``, the two folders the documents name by path, so a command runs as it does in the
checkout's root. ``skynav`` and ``python`` are those of the interpreter running the tests.

One difference from what a user types: ``SKYNAV_MAX_COUNT=2`` (README, "Environment
variables"), which caps the counts that make a run long (dataset frames, ``bench nav`` runs, the
exposures ``calibrate simulate`` averages) and prints one warning line per capped count.

Markers (an HTML comment on the line before a fence, invisible on GitHub)
------------------------------------------------------------------------
- ``<!-- docs-test: skip REASON -->`` before a ``bash`` or ``python`` block: not run; the reason
  shows in pytest's skip summary. Kept few: see :data:`MAX_SKIPS`.
- ``<!-- docs-test: output -->`` before a ``text`` block: lines the previous runnable block
  prints. Each non-blank line must match one of its output lines (stdout and stderr), in order;
  ``...`` in a line matches any text.
- ``<!-- docs-test: file PATH -->`` before a ``json`` block: every ``"key": value`` the block
  shows (strings and numbers) equals the first value of that key in the JSON file PATH (relative
  to the document's folder, depth-first in file order), so a documented example of a written
  file cannot drift from what the command writes.

Every fence names its language (``bash``, ``python``, ``text``, ``json``, ...); a ``skynav``
command outside a ``bash`` block must be a synopsis (a ``[option]``, an upper-case placeholder
like ``DATASET`` or ``...``), so a runnable command cannot hide from this test.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = ("README.md",) + tuple(sorted(f"docs/{p.name}" for p in (ROOT / "docs").glob("*.md")))
#: folders of the checkout that the documents name by path, copied into each document's folder
CARRIED = ("docs/examples", "benchmarks")
#: the documented shrink variable and the cap the docs test runs with
ENV = {"SKYNAV_MAX_COUNT": "2", "MPLBACKEND": "Agg"}
RUNNABLE = ("bash", "python")
MAX_SKIPS = 6
TIMEOUT_S = 600

_FENCE = re.compile(r"^```(\S*)\s*$")
_MARKER = re.compile(r"^<!--\s*docs-test:\s*(\w+)\s*(.*?)\s*-->\s*$")


@dataclass
class Block:
    doc: str            # document, relative to the checkout
    line: int           # 1-based line of the opening fence
    lang: str
    text: str
    marker: tuple | None = None   # (kind, argument) of a docs-test marker before the fence

    @property
    def id(self) -> str:
        return f"{self.doc}:{self.line}"

    @property
    def skip_reason(self) -> str | None:
        return self.marker[1] if self.marker and self.marker[0] == "skip" else None


def parse_blocks(text: str, doc: str) -> list[Block]:
    """The fenced blocks of a Markdown text, with the docs-test marker before each."""
    lines = text.splitlines()
    blocks, i = [], 0
    while i < len(lines):
        m = _FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        j = i + 1
        while j < len(lines) and lines[j].rstrip() != "```":
            j += 1
        if j == len(lines):
            raise ValueError(f"{doc}:{i + 1}: a fence that is never closed")
        k = i - 1
        while k >= 0 and not lines[k].strip():
            k -= 1
        mm = _MARKER.match(lines[k].strip()) if k >= 0 else None
        blocks.append(Block(doc, i + 1, m.group(1), "\n".join(lines[i + 1:j]) + "\n",
                            (mm.group(1), mm.group(2)) if mm else None))
        i = j + 1
    return blocks


def _blocks(doc: str) -> list[Block]:
    return parse_blocks((ROOT / doc).read_text(), doc)


ALL_BLOCKS = [b for d in DOCUMENTS for b in _blocks(d)]
RUN_BLOCKS = [b for b in ALL_BLOCKS if b.lang in RUNNABLE]
CHECK_BLOCKS = [b for b in ALL_BLOCKS if b.marker and b.marker[0] in ("output", "file")]


# ----------------------------------------------------------------------------- running
@dataclass
class Workspace:
    """One document's folder and what its blocks printed so far.

    With a ``state`` file, the progress lives on disk under a lock (``fcntl.flock``), so that
    pytest-xdist workers share one folder per document and run each block once, in order.
    """
    path: Path
    blocks: list
    done: int = -1                               # index of the last block run
    outputs: dict = field(default_factory=dict)  # block index -> combined stdout + stderr
    failed: int | None = None                    # index of a block that failed
    state: Path | None = None

    @contextlib.contextmanager
    def locked(self):
        if self.state is None:
            yield self
            return
        with open(self.state.with_suffix(".lock"), "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if self.state.is_file():
                st = json.loads(self.state.read_text())
                self.done, self.failed = st["done"], st["failed"]
                self.outputs = {int(k): v for k, v in st["outputs"].items()}
            try:
                yield self
            finally:
                self.state.write_text(json.dumps({"done": self.done, "failed": self.failed, "outputs": self.outputs}))


def _env() -> dict:
    env = dict(os.environ)
    env.update(ENV)
    # `skynav` and `python` resolve to the interpreter running the tests (its venv's scripts)
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    env.pop("PYTHONPATH", None)
    return env


def run_block(block: Block, cwd: Path) -> subprocess.CompletedProcess:
    """Run one ``bash`` or ``python`` block in ``cwd``; returns the finished process."""
    scripts = cwd / ".docs-test"
    scripts.mkdir(exist_ok=True)
    stem = re.sub(r"[^A-Za-z0-9]+", "_", block.id)
    if block.lang == "bash":
        # line 1 of the script is this prologue, so the script's line n + 1 is the block's line n
        prologue = ('set -e -o pipefail; trap \'echo "docs-test: exit $? at line $((LINENO - 1 + '
                    f'{block.line})) of {block.doc}" >&2\' ERR\n')
        script = scripts / f"{stem}.sh"
        script.write_text(prologue + block.text)
        cmd = ["bash", str(script)]
    else:
        script = cwd / f"docs_example_{stem}.py"   # a saved script, run from the document's folder
        script.write_text(block.text)
        cmd = [sys.executable, script.name]
    return subprocess.run(cmd, cwd=cwd, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                          timeout=TIMEOUT_S)


def _failure(block: Block, proc: subprocess.CompletedProcess) -> str:
    tail = "\n".join(proc.stdout.splitlines()[-40:])
    return f"{block.id}: the documented {block.lang} block exits with {proc.returncode}\n{block.text}--- output (tail)\n{tail}"


class BlockFailed(AssertionError):
    """A documented block exited non-zero (the message names it and shows its output's tail)."""


_WORKSPACES: dict = {}


@pytest.fixture(scope="session")
def workspaces(tmp_path_factory):
    """``get(doc)``: the document's workspace, one per test run (shared by pytest-xdist workers)."""
    run_id = os.environ.get("PYTEST_XDIST_TESTRUNUID")
    base = tmp_path_factory.getbasetemp()
    root = base.parent / f"docs-test-{run_id}" if run_id else base / "docs-test"
    root.mkdir(parents=True, exist_ok=True)

    def get(doc: str) -> Workspace:
        if doc not in _WORKSPACES:
            slug = re.sub(r"\W+", "_", doc)
            path = root / slug
            with open(root / f"{slug}.lock", "w") as lock:
                fcntl.flock(lock, fcntl.LOCK_EX)
                if not path.is_dir():
                    tmp = root / f"{slug}.tmp"
                    for rel in CARRIED:
                        if (ROOT / rel).is_dir():
                            shutil.copytree(ROOT / rel, tmp / rel, ignore=shutil.ignore_patterns("__pycache__"))
                    tmp.rename(path)
            _WORKSPACES[doc] = Workspace(path, _blocks(doc), state=root / f"{slug}.json")
        return _WORKSPACES[doc]
    return get


def run_through(ws: Workspace, index: int) -> None:
    """Run the document's runnable blocks up to and including ``index``, in order, once each.

    Raises :class:`BlockFailed` naming the block when one fails; a later block of the same
    document is then skipped (it depends on the failed one) rather than reported twice.
    """
    with ws.locked():
        _run_through_unlocked(ws, index)


def _run_through_unlocked(ws: Workspace, index: int) -> None:
    if ws.failed is not None and ws.failed < index:
        pytest.skip(f"depends on {ws.blocks[ws.failed].id}, which failed")
    for i in range(ws.done + 1, index + 1):
        b = ws.blocks[i]
        ws.done = i
        if b.lang not in RUNNABLE or b.skip_reason is not None:
            continue
        proc = run_block(b, ws.path)
        ws.outputs[i] = proc.stdout
        if proc.returncode != 0:
            ws.failed = i
            raise BlockFailed(_failure(b, proc))
    if ws.failed is not None and ws.failed < index:
        pytest.skip(f"depends on {ws.blocks[ws.failed].id}, which failed")


def _run_through(ws: Workspace, index: int) -> None:
    try:
        run_through(ws, index)
    except BlockFailed as exc:  # the block and its output, without the runner's traceback
        pytest.fail(str(exc), pytrace=False)


# ----------------------------------------------------------------------------- output checks
def check_output(shown: str, printed: str) -> list[str]:
    """Lines of ``shown`` (``...`` = any text) not found in ``printed``, in order; [] when all are."""
    out = printed.splitlines()
    missing, pos = [], 0
    for want in (ln.strip() for ln in shown.splitlines()):
        if not want:
            continue
        pat = re.compile("^" + ".*".join(re.escape(p) for p in want.split("...")) + "$")
        for k in range(pos, len(out)):
            if pat.match(out[k].strip()):
                pos = k + 1
                break
        else:
            missing.append(want)
    return missing


def _first(obj, key):
    if isinstance(obj, dict):
        if key in obj:
            return True, obj[key]
        items = obj.values()
    elif isinstance(obj, list):
        items = obj
    else:
        return False, None
    for v in items:
        found, value = _first(v, key)
        if found:
            return True, value
    return False, None


_PAIR = re.compile(r'"(\w+)"\s*:\s*("(?:[^"\\]|\\.)*"|-?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?)')


def check_file(shown: str, path: Path) -> list[str]:
    """``"key": value`` pairs of ``shown`` that differ from the first such key in the JSON ``path``."""
    doc = json.loads(path.read_text())
    bad = []
    for key, raw in _PAIR.findall(shown):
        want = json.loads(raw)
        found, got = _first(doc, key)
        same = found and (got == want if isinstance(want, str) or isinstance(got, str)
                          else isinstance(got, (int, float)) and abs(got - want) <= 1e-9 * max(1.0, abs(want)))
        if not same:
            bad.append(f'"{key}": shown {raw}, the file has {json.dumps(got) if found else "no such key"}')
    return bad


def check_block(ws: Workspace, index: int) -> list[str]:
    """Problems of the output/file check block ``index`` of a run workspace."""
    b = ws.blocks[index]
    kind, arg = b.marker
    if kind == "file":
        path = ws.path / arg
        return [f"{arg}: not written"] if not path.is_file() else check_file(b.text, path)
    prev = max((i for i in ws.outputs if i < index), default=None)
    if prev is None:
        return ["no runnable block before this output block"]
    return [f"not printed by {ws.blocks[prev].id}: {ln}" for ln in check_output(b.text, ws.outputs[prev])]


# ----------------------------------------------------------------------------- the tests
def test_documents_are_collected():
    """A docs run that finds nothing is a broken run, not a passing one."""
    assert "README.md" in DOCUMENTS and len(DOCUMENTS) >= 6
    assert sum(b.lang == "bash" for b in RUN_BLOCKS) >= 12 and sum(b.lang == "python" for b in RUN_BLOCKS) >= 4
    assert CHECK_BLOCKS, "no documented output is checked"


def test_every_fence_names_its_language():
    bare = [b.id for b in ALL_BLOCKS if not b.lang]
    assert not bare, f"fences without a language (bash, python, text, json, ...): {bare}"


def test_commands_outside_bash_blocks_are_synopses():
    """A ``skynav`` line in a non-bash block shows a placeholder, so runnable commands are in bash blocks."""
    placeholder = re.compile(r"\[|\.\.\.|\b[A-Z][A-Z_]{2,}\b")
    hidden = [f"{b.id}: {ln.strip()}" for b in ALL_BLOCKS if b.lang not in RUNNABLE
              for ln in b.text.splitlines() if ln.strip().startswith("skynav ") and not placeholder.search(ln)]
    assert not hidden, "commands outside bash blocks (tag them bash so they run): " + "; ".join(hidden)


def test_skips_are_few_and_say_why():
    skips = [b for b in RUN_BLOCKS if b.skip_reason is not None]
    assert all(len(b.skip_reason) >= 10 for b in skips), [b.id for b in skips]
    assert len(skips) <= MAX_SKIPS, [f"{b.id}: {b.skip_reason}" for b in skips]
    assert all(b.marker[0] in ("skip", "output", "file") for b in ALL_BLOCKS if b.marker)


@pytest.mark.parametrize("block", RUN_BLOCKS, ids=lambda b: b.id)
def test_documented_block_runs(block, workspaces):
    if block.skip_reason is not None:
        pytest.skip(f"{block.id}: {block.skip_reason}")
    ws = workspaces(block.doc)
    _run_through(ws, ws.blocks.index(block))


@pytest.mark.parametrize("block", CHECK_BLOCKS, ids=lambda b: b.id)
def test_documented_output_is_what_runs(block, workspaces):
    ws = workspaces(block.doc)
    index = ws.blocks.index(block)
    _run_through(ws, index)
    with ws.locked():
        problems = check_block(ws, index)
    assert not problems, f"{block.id}: the docs show what the commands do not give:\n" + "\n".join(problems)


def test_cap_is_read_from_the_environment(monkeypatch):
    """SKYNAV_MAX_COUNT caps a count, warns once naming both numbers, and refuses a bad value."""
    from skynav.infra.count_cap import ENV_VAR, cap_count
    from skynav.infra.errors import ConfigValueError, SkynavWarning

    monkeypatch.delenv(ENV_VAR, raising=False)
    assert cap_count(3000, "frames") == 3000
    monkeypatch.setenv(ENV_VAR, "4")
    with pytest.warns(SkynavWarning, match=r"frames capped at 4 \(asked for 3000\)"):
        assert cap_count(3000, "frames") == 4
    assert cap_count(3, "frames") == 3
    with pytest.warns(SkynavWarning):
        assert cap_count(50, "--runs", minimum=5) == 5
    monkeypatch.setenv(ENV_VAR, "0")
    with pytest.raises(ConfigValueError, match=ENV_VAR):
        cap_count(10, "frames")


BROKEN = """# A broken page

```bash
skynav hil facility screen_small -o lab.yaml
skynav no-such-command
echo never reached
```

<!-- docs-test: output -->
```text
wrote lab.yaml: 640x640 px ... screen, ...
```

```python
import sys
sys.exit("a failing example")
```

```python
print("saved as", __file__)
```

<!-- docs-test: output -->
```text
saved as .../docs_example_broken_md_19.py
```

<!-- docs-test: file lab.json -->
```json
{"schema": "skynav.facility/1", "screen": {"width_px": 641}}
```
"""


def test_a_broken_example_fails(tmp_path):
    """The runner as configured above reports a failing command, a failing script and wrong documented output."""
    blocks = parse_blocks(BROKEN, "broken.md")
    assert [b.lang for b in blocks] == ["bash", "text", "python", "python", "text", "json"]
    ws = Workspace(tmp_path, blocks)
    with pytest.raises(BlockFailed, match=r"broken\.md:3: the documented bash block exits with \d+"):
        run_through(ws, 0)
    assert "docs-test: exit 2 at line 5 of broken.md" in ws.outputs[0]   # the failing command, by its line
    assert not (tmp_path / "never").exists() and "never reached" not in ws.outputs[0]
    assert check_block(ws, 1) == []                                   # what the first command printed
    assert check_output("wrote lab.yaml: 641x641 px ... screen, ...", ws.outputs[0]) != []
    # each block runs alone from here (a document run stops at its first failure)
    for i in (2, 3):
        ws.failed, ws.done = None, i - 1
        if i == 2:
            with pytest.raises(BlockFailed, match=r"broken\.md:14: the documented python block exits with 1"):
                run_through(ws, i)
            assert "a failing example" in ws.outputs[2]
        else:
            run_through(ws, i)
    assert check_block(ws, 4) == []                                   # python examples run as saved files
    (tmp_path / "lab.json").write_text(json.dumps({"schema": "skynav.facility/1", "screen": {"width_px": 640}}))
    assert check_block(ws, 5) == ['"width_px": shown 641, the file has 640']
