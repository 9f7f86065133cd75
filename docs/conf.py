"""Sphinx configuration of scatterlab's documentation site (ADR 0093).

The site is built from the Markdown that is also read on GitHub (MyST-Parser: the guide,
the architecture, the decisions) and from the docstrings of the public modules (autodoc,
NumPy-style sections by napoleon). Build it, with every warning an error and every
cross-reference checked::

    .venv/bin/sphinx-build -W --keep-going -n -b html docs build/docs
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the packages themselves, installed or not
sys.path.insert(0, str(ROOT / "docs" / "_ext"))
# autodoc imports the modules: no display, no threaded BLAS (as in the tests)
os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
os.environ.setdefault("MPLBACKEND", "Agg")

from instrument.version import package_version  # noqa: E402

project = "scatterlab"
author = "the scatterlab authors"
copyright = "the scatterlab authors, BSD-3-Clause"
release = package_version()
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
    "scatterlab_docstrings",
    "scatterlab_api",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "screenshots/render.py", "api/generated/*.rst.tmp"]

# --- Markdown (MyST) -------------------------------------------------------------------
# The pages are GitHub Markdown first: headings become link targets as GitHub makes them
# (`file.md#section`), and `$…$` maths renders in both.
myst_enable_extensions = ["dollarmath", "colon_fence"]
myst_heading_anchors = 4

# --- API reference (autodoc) ---------------------------------------------------------
# The modules the reference covers, with their submodules: one page each, written into
# docs/api/generated/ (ignored by git) by docs/_ext/scatterlab_api.py.
api_packages = ["drivers.base", "drivers.errors", "instrument.plans", "instrument.run",
                "instrument.bench", "instrument.pipelines", "analysis",
                "instrument.scripting", "instrument.client", "instrument.protocol"]
# undoc-members: module constants without a doc comment are targets too (the docstrings
# name them: MAX_POINTS, SELECTION_DELTA, ...)
# ignore-module-all: every object on the page of the module that defines it, once (a
# package's __all__ re-exports its submodules' objects).
autodoc_default_options = {"members": True, "undoc-members": True, "show-inheritance": True,
                           "ignore-module-all": True}
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_preserve_defaults = True
# The docstrings are NumPy style (Parameters / Returns sections, ``name : type`` lines):
# docs/_ext/scatterlab_docstrings.py turns them into reST and resolves names as Python does.

# --- Cross-references -------------------------------------------------------------------
# `-n` makes every unresolved reference a warning (and `-W` an error). Annotations name
# other projects' types (NumPy, h5py, the standard library); without their inventories
# (the build fetches nothing) those are left as text. Every reference into scatterlab's own
# packages must resolve.
_EXTERNAL = ("numpy", "np", "npt", "h5py", "scipy", "pathlib", "collections", "typing",
             "types", "enum", "threading", "concurrent", "datetime", "queue", "abc",
             "contextlib", "dataclasses", "os", "io", "re", "sqlite3", "subprocess",
             "logging", "argparse", "xarray", "pandas", "matplotlib", "httpx", "websockets",
             "serial", "usb", "cv2", "ducc0", "tqdm", "dask", "distributed", "importlib",
             "tomllib", "json", "socket", "selectors", "fractions", "decimal", "functools",
             "multiprocessing", "weakref", "asyncio", "uuid", "zlib", "hashlib", "struct",
             "array", "mmap", "tempfile", "shutil", "signal", "time", "math", "random")
nitpick_ignore_regex = [
    (r"py:.*", rf"({'|'.join(_EXTERNAL)})(\..+)?"),
    (r"py:class", r"Path"),  # pathlib.Path imported for type checking only
    # Private helpers (a leading underscore) are not in the reference: a docstring that
    # names one points the reader at the source, where it is rendered as code.
    (r"py:.*", r"(.+\.)?_[A-Za-z]\w*(\.\w+)?"),
    # Pieces of an annotation that autodoc could not evaluate (a type-checking-only
    # import inside a generic: 'dict[str, Foo]'): the signature shows it as written.
    (r"py:class", r"'?\w+\[.*"),
    # Standard-library types named through a module alias or a stub-only module, as the
    # signature writes them: `from importlib import metadata` (metadata.EntryPoint) and
    # _typeshed's WriteableBuffer (a type-checking-only name, no run-time object).
    (r"py:class", r"metadata\.EntryPoint"),
    (r"py:class", r"WriteableBuffer"),
]

# --- HTML -------------------------------------------------------------------------------
html_theme = "alabaster"
html_title = f"scatterlab {release}"
html_static_path: list[str] = []
