"""The frame-timing topic of a paced run: one ``hydroplant_msgs/msg/FrameStats`` message per frame.

``/hydroplant/frame`` carries :class:`sim.live.protocol.FrameStats` in display units, so a Foxglove plot
shows the frame budget directly:

==================  =========================================================================
``index``           frame number, from 0 [-]
``sim_time_s``      simulated time at the end of the frame [s]
``physics_ms``      wall time spent stepping the physics [ms]
``cycle_ms``        wall time from this frame's deadline to the next's start [ms]
``lateness_ms``     how late the frame started against its deadline [ms]
``budget_pct``      ``100 · physics / cycle``: the share of the frame the physics used [%]
``missed``          1 when the physics did not finish before the next deadline, else 0 [-]
==================  =========================================================================

A paced loop may log it to its MCAP (``log.cdr_channel(FRAME_TOPIC, FRAME_STATS,
fields=list(FRAME_FIELDS))`` and ``append(step, frame_row(stats))``); a live Foxglove stream
publishes it itself when the log does not (:class:`sim.live.foxglove_live.FoxgloveLive`).

Example
-------
>>> from sim.live.protocol import FrameStats
>>> frame_row(FrameStats(3, 0.05, 0.004, 1 / 60, 0.0, False))[5]
24.0
"""

from __future__ import annotations

from sim.io.log_schemas import flat_schema
from sim.live.protocol import FrameStats

FRAME_TOPIC = "/hydroplant/frame"
FRAME_FIELDS = {
    "index": "Frame number, from 0 [-]",
    "sim_time_s": "Simulated time at the end of the frame [s]",
    "physics_ms": "Wall time spent stepping the physics [ms]",
    "cycle_ms": "Wall time from this frame's deadline to the next's start [ms]",
    "lateness_ms": "How late the frame started against its deadline [ms]",
    "budget_pct": "100 * physics / cycle: share of the frame the physics used [%]",
    "missed": "1 when the physics did not finish before the next deadline, else 0 [-]",
}
FRAME_STATS = flat_schema("hydroplant_msgs/msg/FrameStats", FRAME_FIELDS)


def budget_percent(stats: FrameStats) -> float:
    """Share of the frame the physics used, ``100 · physics / cycle`` [%] (0 for a zero cycle)."""
    return 100.0 * stats.physics / stats.cycle if stats.cycle > 0 else 0.0


def frame_row(stats: FrameStats) -> tuple[float, ...]:
    """The values of :data:`FRAME_FIELDS`, in order, for one frame."""
    return (float(stats.index), float(stats.sim_time), 1e3 * stats.physics, 1e3 * stats.cycle, 1e3 * stats.lateness,
            budget_percent(stats), 1.0 if stats.missed else 0.0)


__all__ = ["FRAME_FIELDS", "FRAME_STATS", "FRAME_TOPIC", "budget_percent", "frame_row"]
