"""Sphinx configuration of fpscan's documentation site (``bash scripts/docs.sh``).

The site: the user guide (README.md and the pages in docs/, through myst-parser), the API
reference (autodoc + autosummary + numpydoc over the public modules, `reference/index.rst`),
the HTTP reference (rendered from the OpenAPI schema of ``fpscan.service.api.app.create_app``, written
at build time) and a gallery of examples (sphinx-gallery, ``examples/`` at the repository root).
Built with warnings as errors (``sphinx-build -W --keep-going``).
"""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT))
os.environ.setdefault("MPLBACKEND", "Agg")

import fpscan  # after the path is set

project = "fpscan"
author = "the fpscan authors"
copyright = "2026, the fpscan authors"
release = version = fpscan.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "numpydoc",
    "myst_parser",
    "sphinx_gallery.gen_gallery",
    "sphinxcontrib.openapi",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
templates_path = ["_templates"]
# notebook.ipynb runs in tests/public_api/test_notebook.py; results/ holds the experiments' files;
# history/ is the developers' record of dated measurements, not a page of the site
exclude_patterns = ["_build", "_generated", "notebook.ipynb", "results/**", "history/**", "README.md",
                    "auto_examples/*.ipynb", "auto_examples/*.py", "auto_examples/*.zip",
                    "auto_examples/*.md5", "auto_examples/*.json"]

html_theme = "pydata_sphinx_theme"
html_title = f"fpscan {release}"
html_theme_options = {
    "navigation_depth": 2,
    "show_toc_level": 2,
    "secondary_sidebar_items": ["page-toc"],
}
html_sidebars: dict[str, list[str]] = {"readme": [], "index": []}
html_show_sourcelink = False
# code blocks wrap their long lines (docs/_static/wrap.css)
html_static_path = ["_static"]
html_css_files = ["wrap.css"]

# --- myst: the existing markdown pages as they are --------------------------------------
myst_enable_extensions = ["colon_fence", "deflist", "dollarmath"]
myst_heading_anchors = 3
# The pages link to files beside them that are not pages (CHANGELOG.md, *.py, *.json):
# they stay plain links.
suppress_warnings = ["myst.xref_missing", "myst.header",
                    # a page's example JSON with placeholders (architecture.md: [[ix, iy], ...])
                    "misc.highlighting_failure"]

# --- API reference: autodoc + autosummary + numpydoc -----------------------------------------
autosummary_generate = True
autosummary_ignore_module_all = False  # a module's members are its __all__
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "none"  # the docstrings give types and shapes (numpydoc)
autodoc_inherit_docstrings = False
numpydoc_show_class_members = False
numpydoc_show_inherited_class_members = False
numpydoc_class_members_toctree = False
numpydoc_validation_checks: set[str] = set()
numpydoc_xref_param_type = False

# |t|, |w|, |k| (absolute values in the docstrings) are text, not substitutions
rst_prolog = "\n".join(f".. |{name}| replace:: \\|{name}\\|" for name in ("t", "w", "k", "k_lat", "x", "z", "g"))

#: the modules the reference documents (``reference/index.rst``'s autosummary lists)
REFERENCE_MODULES = [line.strip() for line in (DOCS / "reference" / "index.rst").read_text().splitlines()
                     if line.startswith("   ") and line.strip().startswith("fpscan.")]


def home(obj: Any, name: str, default: str) -> str:
    """The reference module that documents ``obj`` (named ``name`` there): of the documented
    modules that export it, the nearest to where it is defined (the longest one that prefixes
    its ``__module__``), else ``default``."""
    import importlib

    defined = getattr(obj, "__module__", None) or ""
    homes = [m for m in REFERENCE_MODULES if (defined == m or defined.startswith(m + "."))
             and name in getattr(importlib.import_module(m), "__all__", ())
             and getattr(importlib.import_module(m), name, None) is obj]
    return max(homes, key=len) if homes else default


def skip_reexport(app: Any, what: str, name: str, obj: Any, skip: bool, options: Any) -> bool | None:
    """Document a name once: a module's re-export of an object that another documented module
    owns (``home``) is left to that module's page (no duplicate object descriptions)."""
    page = getattr(app.env, "temp_data", {}).get("autodoc:module")
    if what == "module" and page and page in REFERENCE_MODULES and home(obj, name, page) != page:
        return True
    return None


# --- the HTTP reference: the OpenAPI schema, written at build time ---------------------------
GENERATED = DOCS / "_generated"


def write_openapi(_app: Any = None) -> Path:
    """Write the service's OpenAPI schema to ``docs/_generated/openapi.json`` and return its path."""
    from fpscan.service.api.app import create_app

    GENERATED.mkdir(exist_ok=True)
    path = GENERATED / "openapi.json"
    schema = create_app(start_workers=False).openapi()
    path.write_text(json.dumps(schema, indent=1, sort_keys=False))
    return path


def write_fpscan_names(_app: Any = None) -> Path:
    """Write the table of :mod:`fpscan`'s names (``docs/_generated/fpscan_names.inc``): an
    autosummary of each name at the module that owns it (``fpscan._EXPORTS``, ``fpscan._RENAMED``)."""
    GENERATED.mkdir(exist_ok=True)
    import importlib

    targets = {name: (module, name) for name, module in fpscan._EXPORTS.items()}
    targets.update(fpscan._RENAMED)
    owners = {}
    for name, (module, attr) in targets.items():
        obj = getattr(importlib.import_module(module), attr)
        owners[name] = f"{home(obj, attr, module)}.{attr}"
    lines = [".. autosummary::", ""]
    # relative to the page's module, fpscan (autosummary refuses a name that repeats it)
    lines += [f"   {owners[name].removeprefix('fpscan.')}" for name in sorted(owners, key=str.lower)]
    path = GENERATED / "fpscan_names.inc"
    path.write_text("\n".join(lines) + "\n")
    return path


# --- the gallery ---------------------------------------------------------------------------
sphinx_gallery_conf = {
    "examples_dirs": str(ROOT / "examples"),
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
    "image_scrapers": ("matplotlib",),
    "reset_modules": ("matplotlib",),
    "abort_on_example_error": False,
    "only_warn_on_example_error": False,
    "show_memory": False,
    "plot_gallery": os.environ.get("FPSCAN_DOCS_GALLERY", "True"),
}


def setup(app: Any) -> None:
    """Write the generated pages' inputs (the OpenAPI schema, fpscan's names) before the pages are read."""
    app.connect("builder-inited", write_openapi)
    app.connect("builder-inited", write_fpscan_names)
    app.connect("autodoc-skip-member", skip_reexport)
