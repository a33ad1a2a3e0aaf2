"""MkDocs hook: lay out the package as it installs, so mkdocstrings reads it from source.

The checkout keeps each import package ``skynav.<room>`` in a top-level folder (``scenes/``,
``renderer/``, ...; pyproject's ``package-dir``), which Python finds through the installed
package's import hook but a static reader (griffe, behind mkdocstrings) does not. This hook makes
a temporary folder holding ``skynav/`` with links to the command line's files and to each room
folder, and puts it first on ``sys.path`` (at the ``startup`` event, before mkdocstrings reads it:
MkDocs restores ``sys.path`` after importing a hook), where griffe looks for ``skynav``. The documented code
is read from the checkout itself (links, not copies), so the API pages always show its docstrings.
"""

from __future__ import annotations

import atexit
import re
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def rooms() -> dict:
    """``{sub-package: folder}`` of pyproject's ``[tool.setuptools] package-dir`` (``skynav.*``)."""
    text = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    line = re.search(r"^package-dir\s*=\s*\{(.*)\}\s*$", text, re.M).group(1)
    pairs = re.findall(r'"skynav\.(\w+)"\s*=\s*"([^"]+)"', line)
    return dict(pairs)


def _layout() -> Path:
    tmp = Path(tempfile.mkdtemp(prefix="skynav-docs-"))
    atexit.register(shutil.rmtree, tmp, ignore_errors=True)
    pkg = tmp / "skynav"
    pkg.mkdir()
    for path in (ROOT / "skynav").glob("*.py"):
        (pkg / path.name).symlink_to(path)
    for name, folder in rooms().items():
        (pkg / name).symlink_to(ROOT / folder, target_is_directory=True)
    return tmp


_SOURCE: list = []


def on_startup(command, dirty):
    if not _SOURCE:
        _SOURCE.append(str(_layout()))
    if _SOURCE[0] not in sys.path:
        sys.path.insert(0, _SOURCE[0])
