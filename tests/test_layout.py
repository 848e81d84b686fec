"""The package layout's rules, read from the sources with :mod:`ast` (nothing is imported).

* ``sim/xpbd`` is the rigid-body solver alone: none of its modules imports :mod:`hydraulics`;
  :mod:`hydraulics` imports nothing from :mod:`sim` (the coupling lives in ``sim/plants``).
* No function of ``hydraulics`` or ``sim`` takes more than ``MAX_PARAMETERS`` parameters
  (``self``/``cls`` not counted): the compiled kernels take named layouts (namedtuples of arrays)
  instead of long positional lists.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_PARAMETERS = 15  # per function, ``self``/``cls`` excluded


def _modules(package: str) -> list[Path]:
    files = sorted((ROOT / package).rglob("*.py"))
    assert files, f"no module under {package}"
    return files


def imported_packages(path: Path) -> set[str]:
    """Top-level names of every package ``path`` imports (``import a.b``, ``from a.b import c``; relative imports
    are inside the package and give none)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module.split(".")[0])
    return found


def parameter_count(function: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Parameters of ``function``: positional-only, positional, keyword-only, ``*args`` and ``**kwargs`` each count
    one; a leading ``self`` or ``cls`` does not."""
    a = function.args
    names = [p.arg for p in (*a.posonlyargs, *a.args)]
    count = len(names) + len(a.kwonlyargs) + (a.vararg is not None) + (a.kwarg is not None)
    return count - 1 if names and names[0] in ("self", "cls") else count


def parameter_counts(package: str) -> list[tuple[int, str]]:
    """(parameter count, ``path:line name``) of every function under ``package``, largest first."""
    rows = []
    for path in _modules(package):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                rows.append((parameter_count(node), f"{path.relative_to(ROOT)}:{node.lineno} {node.name}"))
    return sorted(rows, reverse=True)


def test_the_helpers_read_imports_and_parameters(tmp_path):
    """The AST helpers on a module written here: absolute imports name their package, relative ones none;
    ``self`` is not counted, ``*args``/``**kwargs`` and keyword-only parameters are."""
    path = tmp_path / "probe.py"
    path.write_text("import numpy as np, os.path\nfrom hydraulics._compiled import x\nfrom . import y\n"
                    "class A:\n    def f(self, a, b=1, *c, d, **e):\n        pass\n"
                    "def g(p, /, q):\n    pass\n")
    assert imported_packages(path) == {"numpy", "os", "hydraulics"}
    tree = ast.parse(path.read_text())
    counts = {node.name: parameter_count(node) for node in ast.walk(tree) if isinstance(node, ast.FunctionDef)}
    assert counts == {"f": 5, "g": 2}


@pytest.mark.parametrize("package, forbidden", [("sim/xpbd", "hydraulics"), ("hydraulics", "sim")])
def test_no_import_across_the_layers(package, forbidden):
    """The rigid-body solver does not import the hydraulics, and the hydraulics do not import the simulator."""
    offenders = [str(path.relative_to(ROOT)) for path in _modules(package) if forbidden in imported_packages(path)]
    assert offenders == [], f"{package} modules importing {forbidden}: {offenders}"


@pytest.mark.parametrize("package", ["hydraulics", "sim"])
def test_no_function_takes_more_than_15_parameters(package):
    """Kernels and methods take named layouts, not long positional lists."""
    too_many = [(count, where) for count, where in parameter_counts(package) if count > MAX_PARAMETERS]
    assert too_many == [], f"functions with more than {MAX_PARAMETERS} parameters: {too_many}"
