"""The documentation: every public name in the reference, every page's code run, the site built with -W.

The tutorial, how-to and gallery pages are scripts that the build runs (sphinx-gallery), so a page
whose code fails, or warns, fails the build; the build runs here, in the test suite, so CI runs it.
"""

import re
import subprocess
import sys
from pathlib import Path

import pytest

import gaussfuse

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
MODULES = ("kalman", "diagnostics", "plotting", "io")


def _reference_entries() -> set[str]:
    text = (DOCS / "api.rst").read_text(encoding="utf-8")
    blocks = re.findall(r"\.\. autosummary::\n(?:   :[^\n]*\n)*\n((?:   \S[^\n]*\n)+)", text)
    return {line.strip() for block in blocks for line in block.splitlines()}


def test_every_public_name_is_in_the_reference():
    entries = _reference_entries()
    missing = sorted(set(gaussfuse.__all__) - entries)
    assert not missing, f"docs/api.rst lacks {missing}"
    assert set(MODULES) <= entries
    unknown = sorted(entries - set(gaussfuse.__all__) - set(MODULES))
    assert not unknown, f"docs/api.rst names what gaussfuse does not export: {unknown}"


def test_pages_are_scripts_that_the_build_runs():
    """Prose pages hold no Python to run (it would not be run); the tutorial and how-tos are scripts."""
    for page in DOCS.glob("*.rst"):
        assert ".. code-block:: python" not in page.read_text(encoding="utf-8"), page
    assert len(sorted((DOCS / "tutorial").glob("t0*.py"))) == 8
    assert len(sorted((DOCS / "howto").glob("h0*.py"))) == 6


def test_the_site_builds_without_a_warning(tmp_path):
    pytest.importorskip("sphinx")
    pytest.importorskip("sphinx_gallery")
    pytest.importorskip("numpydoc")
    done = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
                           "-d", str(tmp_path / "doctrees"), str(DOCS), str(tmp_path / "html")],
                          capture_output=True, text=True, timeout=900, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-5000:]
    html = tmp_path / "html"
    for page in ("index", "api", "cli", "changelog", "accuracy", "performance", "auto_tutorial/index",
                 "auto_howto/index", "auto_examples/index", "generated/gaussfuse.filter"):
        assert (html / f"{page}.html").exists(), page
    assert "<table" in (html / "performance.html").read_text(encoding="utf-8")  # the benchmark table (review R16)
    # the figures were drawn: the tutorial's pages have images
    assert list((html / "_images").glob("sphx_glr_t02_*.png"))
