"""The two interfaces between the paced loop of ``hydroplant play`` and the outside world.

A :class:`CommandSource` is asked once per frame for the operator's latest values: named axes of a device
(``left_x``, ``left_y``, ``right_x``, ``right_y``, ``l2``, ``r2``, each in [−1, 1]) or, for a program or a
Foxglove client, valve and pump names of the circuit directly (valve commands [−1, 1], pump speeds [rad/s]).
A mapping section of the scenario turns device axes into valve commands (dead band, expo, inversion, the ISO and
SAE excavator patterns); names the circuit knows pass through unchanged.

A :class:`FrameSink` is shown every frame's result: the MuJoCo generalised positions of the scene's model, a flat
mapping of named values in display units (``"<cylinder>/p_cap_bar"``, ``"<valve>/command"``,
``"frame/physics_ms"`` …) and the frame statistics.  Sinks must not change the simulation: a run with any set
of sinks is bit-identical to one with none.

Example
-------
>>> class Hold:
...     def poll(self, t):
...         return {"boom_valve": 0.5}
...     def close(self):
...         pass
>>> isinstance(Hold(), CommandSource)
True
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class FrameStats:
    """Timing of one paced frame (wall-clock, from ``time.perf_counter``)."""

    index: int
    """Frame number, from 0."""
    sim_time: float
    """Simulated time at the end of the frame [s]."""
    physics: float
    """Wall time spent stepping the physics in this frame [s]."""
    cycle: float
    """Wall time from this frame's deadline to the next's start [s] (the frame period when on time)."""
    lateness: float
    """How late the frame started against its deadline [s] (0 when on time; jitter)."""
    missed: bool
    """True when the physics did not finish before the next frame's deadline."""


@runtime_checkable
class CommandSource(Protocol):
    """Something that supplies operator commands once per frame."""

    def poll(self, t: float) -> Mapping[str, float]:
        """The latest values at simulated time ``t`` [s]: axis names or circuit valve/pump names → value."""

    def close(self) -> None:
        """Release the device or connection."""


@runtime_checkable
class FrameSink(Protocol):
    """Something that shows each frame's state (a viewer, a live stream)."""

    def show(self, t: float, qpos: np.ndarray, values: Mapping[str, float], stats: FrameStats) -> None:
        """Show the state at simulated time ``t`` [s]: MuJoCo ``qpos`` of the scene's model, named values in display
        units, the frame's timing."""

    def close(self) -> None:
        """Close the window or stream."""
