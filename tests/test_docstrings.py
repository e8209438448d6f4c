"""Run the Examples in the core modules' docstrings as doctests."""

from __future__ import annotations

import ast
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


def test_no_docstring_holds_a_control_character():
    """Audit SS4: ``\\top`` and ``\\theta`` in a docstring that is not a raw string are a TAB and "op" (four did:
    the maths rendered broken); one file held the TAB itself. Only newlines belong in a docstring."""
    found = []
    for path in sorted((SRC / "gaussfuse").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
                doc = ast.get_docstring(node, clean=False) or ""
                if any(ord(c) < 32 and c != "\n" for c in doc):
                    found.append(f"{path.relative_to(SRC)}: {getattr(node, 'name', 'the module')}")
    assert not found, found
