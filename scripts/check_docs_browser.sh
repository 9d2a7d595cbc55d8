#!/usr/bin/env bash
# Open built documentation pages in headless Chromium: screenshot each and check that its images loaded.
#
#   bash scripts/check_docs_browser.sh [HTML_DIR] [SHOTS_DIR]
#
# HTML_DIR defaults to docs/_build/html (build it with scripts/docs.sh first), SHOTS_DIR to
# docs/_build/screenshots. Checks the index, getting started and one gallery page
# (scripts/check_docs_browser.py). Needs Debian's chromium (apt-get install -y chromium).
# Exit 0 every page passes, 1 a page fails, 2 no chromium or no build.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
html="${1:-docs/_build/html}"
shots="${2:-docs/_build/screenshots}"
browser="$(command -v chromium || command -v chromium-browser || true)"
if [ -z "$browser" ]; then
    echo "check_docs_browser: chromium not found (apt-get install -y chromium)" >&2
    exit 2
fi
if [ ! -f "$html/index.html" ]; then
    echo "check_docs_browser: $html/index.html not found; run bash scripts/docs.sh first" >&2
    exit 2
fi
python="$(command -v python || command -v python3)"
[ -x .venv/bin/python ] && python=.venv/bin/python
exec "$python" scripts/check_docs_browser.py "$browser" "$html" "$shots" \
    index.html getting_started.html auto_examples/plot_estimate_trajectory.html
