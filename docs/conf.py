"""Sphinx configuration of the omnisim + ifmi documentation (MyST Markdown, numpydoc, sphinx-gallery).

Build with ``bash scripts/docs.sh``. ``DOCS_FAST=1`` skips the gallery's
slow examples (files named ``plot_slow_*.py``).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(DOCS / "_ext"))

import ifmi  # noqa: E402

project = "omnisim + ifmi"
author = "the omnisim + ifmi authors"
copyright = "the omnisim + ifmi authors"  # noqa: A001
release = version = ifmi.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.intersphinx",
    "sphinx.ext.mathjax",
    "numpydoc",
    "sphinx_gallery.gen_gallery",
    "sphinxarg.ext",
    "scene_reference",
    "generated_pages",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
exclude_patterns = ["_build", "_generated", "Thumbs.db", ".DS_Store", "**/GALLERY_HEADER.rst"]
myst_enable_extensions = ["colon_fence", "deflist", "dollarmath"]
myst_heading_anchors = 3

html_theme = "pydata_sphinx_theme"
html_title = "omnisim + ifmi"
html_static_path = []
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
    "footer_start": ["copyright"],
    "footer_end": [],
}
html_show_sourcelink = False

autodoc_typehints = "none"
autodoc_member_order = "bysource"
autosummary_generate = True
numpydoc_show_class_members = False
numpydoc_validation_checks = set()
numpydoc_xref_param_type = False

intersphinx_mapping = {}
nitpicky = False

# The gallery: examples/gallery/plot_*.py, run at build time; plot_slow_* are skipped with DOCS_FAST=1.
fast = os.environ.get("DOCS_FAST", "") not in ("", "0")
sphinx_gallery_conf = {
    "examples_dirs": str(ROOT / "examples" / "gallery"),
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_(?!slow_)" if fast else r"/plot_",
    "ignore_pattern": r"__init__\.py",
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
    "matplotlib_animations": False,
    "reset_modules": ("matplotlib",),
    # A full build runs every example again: after a DOCS_FAST build the slow ones have no figures yet.
    "run_stale_examples": not fast,
}

suppress_warnings = ["config.cache"]


