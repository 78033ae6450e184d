"""Sphinx configuration: sphinx-build -W doc doc/_build/html

The API reference has one page per name of ``dolfinode.__all__``, written into doc/api/generated
when the build starts (see :func:`write_api_pages`), so that a new public object gets its page
without editing the docs.
"""
from pathlib import Path

import dolfinode

project = "dolfinode"
author = "dolfinode developers"
copyright = "dolfinode developers"
release = version = dolfinode.__version__

extensions = ["myst_parser", "sphinx.ext.autodoc", "sphinx.ext.mathjax", "numpydoc"]
myst_enable_extensions = ["dollarmath"]
myst_heading_anchors = 3
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build"]
html_theme = "furo"
html_title = f"dolfinode {release}"

autodoc_member_order = "bysource"
autodoc_default_options = {"members": True, "undoc-members": False}
numpydoc_show_class_members = False
numpydoc_validation_checks = set()
numpydoc_xref_param_type = False

API = Path(__file__).parent / "api" / "generated"


def _directive(name, obj):
    """The autodoc directive documenting ``dolfinode.<name>``."""
    import inspect
    import types

    if inspect.isclass(obj):
        return "autoclass"
    if inspect.isfunction(obj):
        return "autofunction"
    if isinstance(obj, types.ModuleType):
        return "automodule"
    return "autodata"


def _data_source(name, obj):
    """Where a public data object is defined with a ``#:`` comment (autodoc documents a data
    object by that comment; its own __doc__ is its type's)."""
    import sys

    from sphinx.pycode import ModuleAnalyzer

    for modname, module in sorted(sys.modules.items()):
        if not modname.startswith("dolfinode.") or module is None:
            continue
        for attr, value in list(vars(module).items()):
            if value is obj and ("", attr) in ModuleAnalyzer.for_module(modname).find_attr_docs():
                return f"{modname}.{attr}"
    return f"dolfinode.{name}"


def write_api_pages(app=None):
    """One page per public object, api/generated/<name>.rst (autodoc's output is
    reStructuredText); stale pages are removed."""
    API.mkdir(parents=True, exist_ok=True)
    pages = {}
    for name in dolfinode.__all__:
        obj = getattr(dolfinode, name)
        directive = _directive(name, obj)
        if directive == "automodule":
            target = obj.__name__
        elif directive == "autodata":
            target = _data_source(name, obj)
        else:
            target = f"dolfinode.{name}"
        options = "\n   :members:" if directive in ("autoclass", "automodule") else ""
        if directive == "automodule":  # its public classes have their own pages
            shown = [n for n in vars(obj) if n in dolfinode.__all__]
            options += f"\n   :exclude-members: {', '.join(shown)}" if shown else ""
        if directive == "autodata":
            options += "\n   :no-value:"
        title = f"dolfinode.{name}"
        pages[f"{name}.rst"] = (f"{title}\n{'=' * len(title)}\n\n.. {directive}:: {target}"
                                f"{options}\n")
    for stale in {p.name for p in API.iterdir()} - set(pages):
        (API / stale).unlink()
    for file, text in pages.items():
        path = API / file
        if not path.exists() or path.read_text() != text:
            path.write_text(text)


def setup(app):
    app.connect("builder-inited", write_api_pages)
