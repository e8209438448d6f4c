"""The package's layout: no import cycles, kernels that import no driver, numba only in the kernels.

Imports inside functions count: a lazy import is still a dependency.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "gaussfuse"

# What a compiled kernel may import besides the other kernels: numbers, algebra, results, errors.
KERNEL_LEAVES = {"gaussfuse._linalg", "gaussfuse.kalman", "gaussfuse._validation", "gaussfuse.errors",
                 "gaussfuse.inference.results"}


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


MODULES = _modules()


def _imports(name: str) -> set[str]:
    """The package modules `name` imports, anywhere in its file."""
    path = MODULES[name]
    here = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = here
            for _ in range(max(node.level - 1, 0)):
                base = base.rsplit(".", 1)[0]
            root = (base + ("." + node.module if node.module else "")) if node.level else (node.module or "")
            targets = [f"{root}.{a.name}" if f"{root}.{a.name}" in MODULES else root for a in node.names]
        else:
            continue
        for target in targets:
            while target not in MODULES and "." in target:
                target = target.rsplit(".", 1)[0]
            # a package's own __init__ is not an edge for the modules inside it, nor the root package
            if target in MODULES and target != name and target != "gaussfuse" and not name.startswith(target + "."):
                found.add(target)
    return found


GRAPH = {name: _imports(name) for name in MODULES}


def test_no_import_cycles():
    index, low, stack, on, cycles = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in GRAPH[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in GRAPH:
        if v not in index and v != "gaussfuse":
            visit(v)
    assert cycles == []


@pytest.mark.parametrize("name", sorted(n for n in MODULES if n.startswith("gaussfuse._kernels.")))
def test_kernels_import_no_driver(name):
    outside = {t for t in GRAPH[name] if not t.startswith("gaussfuse._kernels") and t not in KERNEL_LEAVES}
    assert outside == set()


def test_numba_is_imported_only_by_the_kernels():
    for name, path in MODULES.items():
        if name.startswith("gaussfuse._kernels"):
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                assert not any(a.name.split(".")[0] == "numba" for a in node.names), name
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                assert (node.module or "").split(".")[0] != "numba", name


def test_the_graph_has_the_edges_it_should():
    """The graph is real: the front functions import the drivers, which import the registry."""
    assert "gaussfuse.inference.drivers" in GRAPH["gaussfuse.inference"]
    assert "gaussfuse.inference.registry" in GRAPH["gaussfuse.inference.drivers"]
    assert "gaussfuse._kernels.linear" not in GRAPH["gaussfuse.inference.drivers"]  # a computed name


def test_covariances_are_factorised_only_in_the_linear_algebra_modules():
    """No np.linalg.cholesky, solve, inv, lstsq or pinv outside _linalg, kalman and the kernels."""
    allowed = {"gaussfuse._linalg", "gaussfuse.kalman"}
    banned = {"cholesky", "solve", "inv", "lstsq", "pinv"}
    found = []
    for name, path in MODULES.items():
        if name in allowed or name.startswith("gaussfuse._kernels"):
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if (isinstance(node, ast.Attribute) and node.attr in banned and isinstance(node.value, ast.Attribute)
                    and node.value.attr == "linalg"):
                found.append(f"{name}:{node.lineno} linalg.{node.attr}")
    assert found == []


def test_the_package_exports_every_model_name():
    """gaussfuse.__all__ is written out for type checkers; it must not drift from models.__all__."""
    import gaussfuse
    import gaussfuse.models

    assert set(gaussfuse.models.__all__) <= set(gaussfuse.__all__)
    assert len(gaussfuse.__all__) == len(set(gaussfuse.__all__))
    assert all(getattr(gaussfuse, name) is getattr(gaussfuse.models, name) for name in gaussfuse.models.__all__)
