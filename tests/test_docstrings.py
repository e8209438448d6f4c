"""Run the Examples in the core modules' docstrings as doctests."""

from __future__ import annotations

import contextlib
import doctest
import importlib
import io

import pytest

MODULES = [
    "gaussfuse.gaussian",
    "gaussfuse.inference",
    "gaussfuse.online",
    "gaussfuse.models.linear",
    "gaussfuse.models.motion",
    "gaussfuse.models.nonlinear",
    "gaussfuse.linearize.sigma_points",
    "gaussfuse.forecasting",
    "gaussfuse.simulation",
]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    module = importlib.import_module(name)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        result = doctest.testmod(module, optionflags=doctest.NORMALIZE_WHITESPACE, report=True)
    assert result.attempted > 0, f"{name} has no docstring examples"
    assert result.failed == 0, out.getvalue()
