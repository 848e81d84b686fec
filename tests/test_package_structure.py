"""Structure of the ``hydraulics`` package: no import cycles (short signatures: ``test_layout.py``).

* The module-level imports of ``hydraulics`` form no cycle (imports inside functions are deferred and not
  counted), and ``hydraulics`` imports nothing from ``sim``.
"""

from __future__ import annotations

import ast

from conftest import ROOT

PACKAGE = ROOT / "hydraulics"


def _modules():
    """Module name → (path, is package) of every module of ``hydraulics``."""
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        out[".".join(parts[:-1] if is_package else parts)] = (path, is_package)
    return out


def _module_level_imports(name, path, is_package):
    """Absolute names a module imports at module level (in try/if blocks too), relative imports resolved."""
    package = name if is_package else name.rsplit(".", 1)[0]
    found = set()
    statements = list(ast.parse(path.read_text(encoding="utf-8")).body)
    while statements:
        node = statements.pop()
        if isinstance(node, (ast.Try, ast.If)):
            statements += node.body + node.orelse + [s for h in getattr(node, "handlers", []) for s in h.body]
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[:len(parts) - node.level + 1] + ([node.module] if node.module else []))
            found.add(base)
            found.update(f"{base}.{a.name}" for a in node.names)
    return found


def test_no_import_cycle_and_no_import_of_sim():
    """Depth-first search over the module-level import graph finds no cycle; no module imports ``sim``."""
    modules = _modules()
    imports = {name: _module_level_imports(name, *info) for name, info in modules.items()}
    assert not [name for name, found in imports.items() if any(i == "sim" or i.startswith("sim.") for i in found)]
    graph = {name: {i for i in found if i in modules and i != name} for name, found in imports.items()}
    state = {}  # 1: on the current path, 2: done

    def visit(name, path):
        state[name] = 1
        for other in sorted(graph[name]):
            assert state.get(other) != 1, f"import cycle: {' -> '.join(path + [other])}"
            if other not in state:
                visit(other, path + [other])
        state[name] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name, [name])
    assert len(graph) > 20 and graph["hydraulics._compiled"]  # the graph was built
