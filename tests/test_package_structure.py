"""Structure of the packages: no import cycle, counting every import (short signatures: ``test_layout.py``).

* Every import statement of ``hydraulics`` and ``sim`` counts, at module level and inside functions alike: a deferred import
  hides a cycle from Python's import machinery but not from the reader, so none may close one.
* ``hydraulics`` imports nothing from ``sim`` (it is usable alone).
* ``from package import name`` depends on the submodule ``package.name`` when that is a module, else on
  ``package`` (its ``__init__``).
"""

from __future__ import annotations

import ast

from conftest import ROOT

PACKAGES = ("hydraulics", "sim")


def _modules(packages):
    """Module name → (path, is package) of every module of ``packages``."""
    out = {}
    for package in packages:
        for path in (ROOT / package).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            is_package = parts[-1] == "__init__"
            out[".".join(parts[:-1] if is_package else parts)] = (path, is_package)
    return out


def imports(name, path, is_package, modules):
    """Absolute names of the modules that module ``name`` imports anywhere in its file (relative imports resolved;
    outside ``modules`` the names are kept as written)."""
    package = name if is_package else name.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[:len(parts) - node.level + 1] + ([node.module] if node.module else []))
            submodules = {f"{base}.{a.name}" for a in node.names} & set(modules)
            found.update(submodules)
            if len(submodules) < len(node.names):  # some names are attributes of the module ``base`` itself
                found.add(base)
    return found


def find_cycle(graph):
    """A list of module names closing a cycle of ``graph`` (name → set of names), or None."""
    state = {}  # 1: on the current path, 2: done

    def visit(name, path):
        state[name] = 1
        for other in sorted(graph[name]):
            if state.get(other) == 1:
                return path + [other]
            if other not in state:
                cycle = visit(other, path + [other])
                if cycle:
                    return cycle
        state[name] = 2
        return None

    for name in sorted(graph):
        if name not in state:
            cycle = visit(name, [name])
            if cycle:
                return cycle
    return None


def test_find_cycle_finds_a_deferred_import_cycle(tmp_path):
    """The checker itself: an import inside a function that closes a cycle is found."""
    (tmp_path / "a.py").write_text("import b\n")
    (tmp_path / "b.py").write_text("def f():\n    from a import x\n")
    modules = {"a": (tmp_path / "a.py", False), "b": (tmp_path / "b.py", False)}
    graph = {n: {i for i in imports(n, *info, modules) if i in modules and i != n} for n, info in modules.items()}
    assert find_cycle(graph) in (["a", "b", "a"], ["b", "a", "b"])


def test_no_import_cycle_and_no_import_of_sim():
    """Depth-first search over the graph of every import finds no cycle; no module of ``hydraulics`` imports ``sim``."""
    modules = _modules(PACKAGES)
    found = {name: imports(name, *info, modules) for name, info in modules.items()}
    assert not [name for name, names in found.items()
                if name.startswith("hydraulics") and any(i == "sim" or i.startswith("sim.") for i in names)]
    graph = {name: {i for i in names if i in modules and i != name} for name, names in found.items()}
    cycle = find_cycle(graph)
    assert cycle is None, f"import cycle: {' -> '.join(cycle)}"
    assert len(graph) > 20 and graph["hydraulics._compiled"]  # the graph was built
