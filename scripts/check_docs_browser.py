"""Open built documentation pages in headless Chromium, screenshot them and check their images loaded.

Usage: ``python scripts/check_docs_browser.py CHROMIUM HTML_DIR SHOTS_DIR PAGE...``
(``scripts/check_docs_browser.sh`` passes the defaults).

For each page (relative to HTML_DIR):

* a screenshot is written to SHOTS_DIR and must not be blank (more than one
  colour);
* a copy of the page with one added script, which writes each ``<img>``'s
  ``naturalWidth`` into the DOM once the page has loaded, is opened with
  ``--dump-dom``: every image must have loaded (width > 0), and the page must
  show at least one image.

Prints one line per page; exits 1 when a page fails.
"""

from __future__ import annotations

import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from matplotlib.image import imread

# Chromium's switches for a headless run that touches no network and no profile of the user's.
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run", "--hide-scrollbars",
         "--window-size=1280,1400", "--virtual-time-budget=8000")
# Added to the page copy: record every image's loaded width as an attribute the DOM dump shows.
_PROBE = ("<script>window.addEventListener('load', function () {"
          "document.querySelectorAll('img').forEach(function (img) {"
          "img.setAttribute('data-loaded-width', img.complete ? img.naturalWidth : 0);});});</script>")
# Seconds a page may take in Chromium.
TIMEOUT_S = 120


def _chromium(browser: str, profile: str, *args: str) -> str:
    run = subprocess.run([browser, *FLAGS, f"--user-data-dir={profile}", *args], capture_output=True,
                         text=True, timeout=TIMEOUT_S, check=False)
    return run.stdout


def check_page(browser: str, page: Path, shot: Path) -> list[str]:
    """Problems of one page (empty when it passes)."""
    problems = []
    with tempfile.TemporaryDirectory() as profile:
        _chromium(browser, profile, f"--screenshot={shot}", page.resolve().as_uri())
    if not shot.is_file():
        return ["no screenshot was written"]
    pixels = imread(shot)
    if np.ptp(pixels[..., :3]) == 0:
        problems.append("the screenshot is blank")
    probe = page.with_name(page.stem + ".browser-check.html")
    probe.write_text(page.read_text(encoding="utf-8").replace("</body>", _PROBE + "</body>"), encoding="utf-8")
    try:
        with tempfile.TemporaryDirectory() as profile:
            dom = _chromium(browser, profile, "--dump-dom", probe.resolve().as_uri())
    finally:
        probe.unlink()
    widths = [int(w) for w in re.findall(r'data-loaded-width="(\d+)"', dom)]
    images = len(re.findall(r"<img\b", dom))
    if images == 0:
        problems.append("no image on the page")
    elif len(widths) < images:
        problems.append(f"only {len(widths)} of {images} images were probed (the page did not finish loading)")
    broken = sum(w == 0 for w in widths)
    if broken:
        problems.append(f"{broken} of {images} images did not load")
    return problems


def main(argv: list[str]) -> int:
    browser, html, shots, *pages = argv
    html, shots = Path(html), Path(shots)
    shots.mkdir(parents=True, exist_ok=True)
    status = 0
    for name in pages:
        shot = shots / (name.replace("/", "_").removesuffix(".html") + ".png")
        problems = check_page(browser, html / name, shot)
        status |= bool(problems)
        print(f"{name}: {'; '.join(problems) if problems else 'ok'} (screenshot {shot})")
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
