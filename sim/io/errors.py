"""The error a wrong scenario raises, in a module of its own so that the scenario reader (:mod:`sim.io.scenario`)
and the readers of its sections (:mod:`sim.live.mapping`) can both raise it without importing each other.

Example
-------
>>> issubclass(ScenarioError, CircuitError)
True
"""

from __future__ import annotations

from hydraulics.components import CircuitError


class ScenarioError(CircuitError):
    """A scenario file is wrong; the message names the file and the field."""


__all__ = ["ScenarioError"]
