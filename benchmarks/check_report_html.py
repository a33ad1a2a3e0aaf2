"""Load a ``skynav bench ip`` report.html in headless Chromium (Debian's ``chromium`` package):
no console errors, and a screenshot showing the plots.

Usage::

    python benchmarks/check_report_html.py REPORT_DIR/report.html [-o screenshot.png]

Exit code 0 when the page loads with no console message of level error and every embedded image
decodes (checked in the page: ``naturalWidth > 0``), 1 otherwise; the screenshot is written next
to the report unless ``-o`` says where.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path


def chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


def check(html: Path, screenshot: Path) -> tuple[bool, str]:
    exe = chromium()
    if exe is None:
        return False, "no chromium on PATH (Debian: apt-get install chromium)"
    url = html.resolve().as_uri()
    with tempfile.TemporaryDirectory() as profile:
        base = [exe, "--headless", "--no-sandbox", "--disable-gpu", f"--user-data-dir={profile}",
                "--enable-logging=stderr", "--v=0", "--window-size=1200,2600"]
        shot = subprocess.run(base + [f"--screenshot={screenshot}", url], capture_output=True, text=True, timeout=120)
        # the images decoded: the page's own view of every <img>, read back through the DOM
        probe = html.parent / "_img_probe.html"
        probe.write_text(html.read_text(encoding="utf-8").replace(
            "</body>", "<script>window.onload=function(){var b=[].filter.call(document.images,function(i){"
            "return !(i.naturalWidth>0)}).length;document.title='IMAGES '+document.images.length+' BROKEN '+b;"
            "}</script></body>"), encoding="utf-8")
        try:
            dom = subprocess.run(base + ["--virtual-time-budget=5000", "--dump-dom", probe.resolve().as_uri()],
                                 capture_output=True, text=True, timeout=120)
        finally:
            probe.unlink(missing_ok=True)
    console = [line for line in shot.stderr.splitlines() if "CONSOLE" in line or ":ERROR:" in line and "console" in line.lower()]
    errors = [line for line in console if re.search(r"CONSOLE\(\d+\)|Uncaught|error", line, re.I)]
    m = re.search(r"<title>IMAGES (\d+) BROKEN (\d+)</title>", dom.stdout)
    n_img, broken = (int(m.group(1)), int(m.group(2))) if m else (0, -1)
    ok = shot.returncode == 0 and screenshot.exists() and not errors and n_img >= 3 and broken == 0
    return ok, f"screenshot {screenshot} ({screenshot.stat().st_size if screenshot.exists() else 0} bytes), " \
               f"{n_img} images, {broken} broken, {len(errors)} console errors" + ("".join("\n  " + e for e in errors))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("html")
    ap.add_argument("-o", "--output", default=None)
    a = ap.parse_args(argv)
    html = Path(a.html)
    shot = Path(a.output) if a.output else html.with_name("report_screenshot.png")
    ok, msg = check(html, shot)
    print(("OK: " if ok else "FAILED: ") + msg)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
