"""Run the Examples in the core modules' docstrings as doctests."""

from __future__ import annotations

import contextlib
import doctest
import importlib
import io
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
MODULES = sorted(".".join(path.relative_to(SRC).with_suffix("").parts).removesuffix(".__init__")
                 for path in (SRC / "gaussfuse").rglob("*.py") if ">>>" in path.read_text(encoding="utf-8"))
"""Every module with an example in a docstring (a fixed list left out learning's, whose Nile figure was wrong)."""


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    module = importlib.import_module(name)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        result = doctest.testmod(module, optionflags=doctest.NORMALIZE_WHITESPACE, report=True)
    assert result.attempted > 0, f"{name} has no docstring examples"
    assert result.failed == 0, out.getvalue()
