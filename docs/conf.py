"""Sphinx configuration of gaussfuse's documentation: ``sphinx-build -W -b html docs docs/_build/html``.

The tutorial, the how-to guides and the gallery are sphinx-gallery scripts
(``docs/tutorial``, ``docs/howto``, ``examples``): the build runs every one
of them, so every code block on every page is executed and its figures are
the ones drawn. The API reference is generated from the numpydoc docstrings,
and numpydoc's validation fails the build on a public callable with a
missing parameter or section.
"""

import os
import sys
from importlib.metadata import version as _version

sys.path.insert(0, os.path.abspath(os.path.dirname(__file__)))

project = "gaussfuse"
author = "the gaussfuse developers"
copyright = "2026, the gaussfuse developers"
release = _version("gaussfuse")
version = release

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "numpydoc",
    "sphinx_gallery.gen_gallery",
    "myst_parser",
]

# The command line's help, as its parser prints it (docs/cli.rst includes these files).
_generated = os.path.join(os.path.dirname(__file__), "_generated")
os.makedirs(_generated, exist_ok=True)
from gaussfuse.cli import build_parser  # noqa: E402

_parser = build_parser()
for _name, _command in [("gaussfuse", _parser), *(
        (f"gaussfuse-{name}", sub) for action in _parser._subparsers._group_actions
        for name, sub in action.choices.items())]:
    with open(os.path.join(_generated, f"{_name}.txt"), "w", encoding="utf-8") as _f:
        _f.write(_command.format_help())

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "_generated", "**/*.ipynb", "**/*.zip", "**.md5", "**/*.py", "tutorial", "howto"]
templates_path = ["_templates"]

html_theme = "pydata_sphinx_theme"
html_title = f"gaussfuse {release}"
html_theme_options = {"navigation_with_keys": False, "show_toc_level": 2}

autosummary_generate = True
autodoc_default_options = {"members": True, "inherited-members": False}
autodoc_typehints = "none"  # the numpydoc type fields carry the shapes

numpydoc_show_class_members = False
numpydoc_xref_param_type = False
numpydoc_validation_checks = {"PR01", "PR02", "PR03", "RT02", "GL08"}
# PR01: a parameter without an entry; PR02: an entry for no parameter; PR03: in the wrong order;
# RT02: a bare "Returns" type with a name only; GL08: a public object without a docstring.
# Results (built by gaussfuse, never by users) are documented by their Attributes, not Parameters.
_RESULTS = ["FilterResult", "SmoothResult", "Stationary", "IMMResult", "Fused", "FitResult", "Forecast", "Simulation"]
# count and index of a NamedTuple are tuple's own methods; dim, q and noise of the integrated white-noise
# motions are slots (which hold no docstring), described in their classes' Parameters.
numpydoc_validation_exclude = {r"\.__\w+__$", r"\._\w+$", r"\.(count|index)$",
                               r"^gaussfuse\.Constant(Position|Velocity|Acceleration)\.(dim|q|noise)$",
                               *(rf"^gaussfuse\.{name}$" for name in _RESULTS)}

# numpydoc 1.11 fails on a member whose source has no def or class line (an alias such as
# ``__call__ = predict``): it looks for one with next() and lets StopIteration escape. Such a
# member has no line of its own to attach an ignore comment to, so answer "no line".
import numpydoc.validate as _validate  # noqa: E402

_def_line = _validate.Validator.source_file_def_line.fget


def _def_line_or_none(self):
    try:
        return _def_line(self)
    except StopIteration:
        return None


_validate.Validator.source_file_def_line = property(_def_line_or_none)

sphinx_gallery_conf = {
    "examples_dirs": ["tutorial", "howto", "../examples"],
    "gallery_dirs": ["auto_tutorial", "auto_howto", "auto_examples"],
    "filename_pattern": r"\.py$",  # run every script
    "ignore_pattern": r"__init__\.py|/_",
    "within_subsection_order": "FileNameSortKey",
    "download_all_examples": False,
    "reset_argv": "gallery_argv.reset_argv",
    "abort_on_example_error": True,
    "remove_config_comments": True,
    "matplotlib_animations": False,
    "image_scrapers": ("matplotlib",),
    "show_memory": False,
}
