"""The example scenes shipped with hydroplant (the repository's ``models/`` folder).

In a checkout the examples are ``models/`` beside the packages; an installed
wheel carries the same files as the package ``sim.examples``.  An example is
named by its folder and scenario stem, e.g. ``excavator/dig`` for
``models/excavator/dig.scenario.toml``::

    from sim.io.examples import example_path, examples
    path = example_path("boom/lift")          # Path to the scenario file
    for name, summary in examples(): print(name, summary)
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

from hydraulics.components import CircuitError

SCENARIO_SUFFIX = ".scenario.toml"


def examples_root() -> Path:
    """The folder holding the example scenes: the installed ``sim.examples`` package, else the checkout's ``models/``."""
    spec = importlib.util.find_spec("sim.examples")
    if spec is not None and spec.submodule_search_locations:
        for location in spec.submodule_search_locations:
            if Path(location).is_dir():
                return Path(location)
    return Path(__file__).resolve().parents[2] / "models"


def _summary(path: Path) -> str:
    """The first comment line of a scenario file (its title), without the ``#``."""
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("#"):
            return line.lstrip("#").strip()
        if line.strip():
            break
    return ""


def examples() -> list[tuple[str, str]]:
    """(name, one-line summary) of every shipped scenario, sorted by name."""
    root = examples_root()
    found = sorted(root.glob(f"*/*{SCENARIO_SUFFIX}"))
    return [(f"{p.parent.name}/{p.name.removesuffix(SCENARIO_SUFFIX)}", _summary(p)) for p in found]


def example_path(name: str) -> Path:
    """The scenario file of the example ``name`` (``scene/scenario``); an unknown name raises :class:`CircuitError`."""
    path = examples_root() / f"{name}{SCENARIO_SUFFIX}"
    if "/" not in name or ".." in Path(name).parts or not path.is_file():
        known = ", ".join(n for n, _ in examples())
        raise CircuitError(f"--example {name!r}: no such example (known: {known})")
    return path


def example_file(relative: str) -> Path:
    """A file of the examples folder by its relative path (e.g. ``lift_1dof/lift.circuit.toml``)."""
    return examples_root() / relative
