#!/usr/bin/env bash
# Build the documentation site into docs/_build/html (warnings are errors).
#
#   bash scripts/docs.sh                # everything, the gallery's examples run
#   DOCS_FAST=1 bash scripts/docs.sh    # skip the slow gallery examples (plot_slow_*.py)
#   bash scripts/docs.sh linkcheck      # also check every internal link of the built pages
#
# Installs the project (scripts/setup.sh) and the docs extra into .venv when missing.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/setup.sh"

stamp=".venv/.docs-installed-$(sha256sum pyproject.toml | cut -c1-16)"
if [ ! -f "$stamp" ]; then
    echo "docs: installing the docs extra into .venv ..."
    if ! python -m pip install -e ".[sim,test,docs]" > .venv/docs-setup.log 2>&1; then
        tail -n 30 .venv/docs-setup.log >&2
        echo "docs: installation failed; full log in .venv/docs-setup.log" >&2
        exit 1
    fi
    rm -f .venv/.docs-installed-*
    touch "$stamp"
fi

start=$(date +%s)
export MPLBACKEND=Agg
python -m sphinx -W --keep-going -b html -d docs/_build/doctrees docs docs/_build/html
pages=$(find docs/_build/html -name '*.html' -not -path '*/_static/*' -not -name 'genindex.html' \
        -not -name 'search.html' -not -path '*/_modules/*' | wc -l)
echo "docs: built $pages pages in $(( $(date +%s) - start ))s: docs/_build/html/index.html"
if [ "${1:-}" = "linkcheck" ]; then
    python scripts/check_docs_links.py docs/_build/html
fi
