"""Sphinx configuration of canfdi's documentation site.

Build it with `python -m sphinx -W -b html docs docs/_build/html` (after `pip install -e
'.[docs]'`): warnings are errors, so a broken internal link, a missing page or a bad docstring
fails the build. The reference pages are generated from the code at build time and the
figures from runs of the emulator and the monitor (docs/_ext/canfdi_docs.py).
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))

project = "canfdi"
author = "the canfdi developers"
copyright = "2026, the canfdi developers"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "canfdi_docs",
]
source_suffix = {".md": "markdown"}
root_doc = "index"
# what the build generates is included by the reference pages, not read as pages of its own
exclude_patterns = ["_build", "_generated"]
# a numpy docstring's "k : (N,) samples" names several attributes called k: not a link to fix
suppress_warnings = ["ref.python"]

myst_heading_anchors = 3
myst_enable_extensions = ["colon_fence"]

autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_default_options = {"members": True, "show-inheritance": False}
napoleon_google_docstring = False
napoleon_numpy_docstring = True
# an Attributes section as fields of its class, not as attributes described a second time
napoleon_use_ivar = True

html_theme = "furo"
html_title = "canfdi"
html_static_path = ["_static"]
# without one a browser asks for /favicon.ico, which is no page of the site: a console error
html_favicon = "_static/favicon.svg"
# The fleet's HTML report of the fleet tutorial, as `canfdi fleet` wrote it during the build
# (into a directory that must exist when this file is read, before the build fills it).
(HERE / "_generated" / "site-extra").mkdir(parents=True, exist_ok=True)
html_extra_path = ["_generated/site-extra"]
