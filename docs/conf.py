"""Sphinx configuration of the transient-mi documentation site (``bash run.sh docs``).

The pages are the Markdown files of ``docs/`` (MyST) plus reference pages that
``docs/_ext/tmi_reference.py`` generates at every build into ``docs/_generated/``
(git-ignored): one per XML plug-in, from the project's plug-in registry; the Python
API of the public names; the CLI from the click commands; the figure gallery.
Built with ``-W --keep-going -n`` (tests/test_docs_site.py).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(DOCS / "_ext"))
os.environ.setdefault("TRANSIENT_MI_PROGRESS", "0")

import transient_mi  # noqa: E402,F401  (sets up LLVM and the variant before autodoc imports anything)

project = "transient-mi"
author = "transient-mi developers"
copyright = "transient-mi developers"
release = version = transient_mi.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "numpydoc",
    "tmi_reference",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "examples", "img/*.py", "Thumbs.db", ".DS_Store"]
templates_path: list[str] = []

# Markdown: GitHub-style heading anchors (the pages link to `page.md#some-heading`, which works on GitHub
# and here), and $...$ is not maths (the pages quote shell variables and prices).
myst_heading_anchors = 4
myst_enable_extensions = ["colon_fence"]

# autodoc: public names only (the generator lists them from __all__ / the lazy export tables);
# type hints stay in the signature, the numpydoc sections describe the parameters.
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_default_options = {"members": False}
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

# Nitpicky (-n): every reference must resolve, except to targets this site does not document on purpose:
# private modules and helpers (a leading underscore; the docstrings cite them for readers of the code)
# and the third-party libraries (no network at build time, so no intersphinx).
nitpick_ignore_regex = [
    (r"py:.*", r"(.*\.)?_[A-Za-z0-9].*"),
    (r"py:.*", r"(mi|mitsuba|dr|drjit|np|numpy|scipy|trimesh|typer|click|rich|bokeh|h5py|dask|pathlib|os|"
               r"collections|typing|numba|matplotlib)(\..*)?"),
    (r"py:class", r"(Path|ndarray|optional|callable|array_like|array-like)"),
]

html_theme = "alabaster"
html_title = "transient-mi"
html_static_path: list[str] = []
html_show_sourcelink = False
