"""Operator commands held per frame: the inputs of ``hydroplant play`` and of the replay of its log.

A paced run reads its command source once per frame and holds the values over the frame's physics steps (zero-order
hold at the frame rate).  :class:`CommandTable` keeps those values, one row per frame, with the frame's first step;
each circuit input (valve command [-] or pump speed [rev/s]) is then a :class:`HeldInput`, a schedule of the
scenario's ``inputs`` that the plants sample per (sub)step like any other (:func:`sim.plants.inputs.sample_inputs`
calls its :meth:`HeldInput.sample`).  The value at time t is the row of the last frame that started at or before t:

    u(t) = values[k],  k = max{ j : steps[j]·dt <= t }   (values[0] before the first frame)

with the frame start time computed as ``steps[j] * dt``, the same product the plants form for a step's time, so a
step that opens a frame takes that frame's row exactly.  The live run appends a row per frame as it goes; the
replay builds the same table from the log's ``/hydroplant/commands`` topic (:func:`table_from_log`) and so feeds
every step the same float64 values: the replay is bit for bit the original run.

Example
-------
>>> table = CommandTable(["boom_valve", "pump"], dt=0.001)
>>> table.append(0, [0.0, 33.3])
>>> table.append(17, [0.5, 33.3])
>>> boom = table.inputs()["boom_valve"]
>>> boom(0.016), boom(0.017)
(0.0, 0.5)
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

COMMANDS_TOPIC = "/hydroplant/commands"


class CommandTable:
    """Rows of commands per frame: ``steps`` (int, the frame's first step) and ``values`` (frames × inputs).

    ``names`` are the circuit's valve and pump names, in column order; ``dt`` [s] the physics step.
    """

    def __init__(self, names: Sequence[str], dt: float, *, steps=None, values=None):
        self.names = tuple(names)
        self.dt = float(dt)
        width = len(self.names)
        if steps is None:
            self._steps = np.zeros(64, np.int64)
            self._values = np.zeros((64, width))
            self._times = np.zeros(64)
            self.count = 0
        else:
            steps = np.asarray(steps, np.int64)
            values = np.asarray(values, float).reshape(len(steps), width)
            if len(steps) == 0:
                raise ValueError("a command table needs at least one row")
            if np.any(np.diff(steps) <= 0):
                raise ValueError("command rows must have strictly increasing steps")
            self._steps, self._values = steps.copy(), values.copy()
            self._times = self._steps * self.dt
            self.count = len(steps)

    @property
    def steps(self) -> np.ndarray:
        """First step of each frame (int64)."""
        return self._steps[:self.count]

    @property
    def values(self) -> np.ndarray:
        """Commands of each frame, one column per name."""
        return self._values[:self.count]

    def append(self, step: int, values) -> None:
        """Add the commands of the frame that starts at ``step`` (after every earlier frame)."""
        step = int(step)
        n = self.count
        if n and step <= self._steps[n - 1]:
            raise ValueError(f"frame step {step} is not after the previous frame's {int(self._steps[n - 1])}")
        if n == len(self._steps):
            self._steps = np.concatenate([self._steps, np.zeros(n, np.int64)])
            self._values = np.concatenate([self._values, np.zeros_like(self._values)])
            self._times = np.concatenate([self._times, np.zeros(n)])
        self._steps[n] = step
        self._times[n] = step * self.dt
        self._values[n] = values
        self.count = n + 1

    def rows_at(self, times) -> np.ndarray:
        """Index of the row in force at each of ``times`` [s] (the first row before the first frame)."""
        index = np.searchsorted(self._times[:self.count], times, side="right") - 1
        return np.maximum(index, 0)

    def inputs(self) -> dict:
        """One :class:`HeldInput` per name: the scenario ``inputs`` that replay this table."""
        return {name: HeldInput(self, j) for j, name in enumerate(self.names)}

    def after(self, step: int) -> "CommandTable":
        """The rows in force from ``step`` on (the row in force at ``step`` first, moved to ``step``)."""
        first = int(self.rows_at(step * self.dt))
        steps = self.steps[first:].copy()
        steps[0] = max(int(steps[0]), int(step))
        return CommandTable(self.names, self.dt, steps=steps, values=self.values[first:])


class HeldInput:
    """One column of a :class:`CommandTable` as a scenario input: callable of time [s], and vectorised
    (:meth:`sample`) for the plants that sample whole blocks of (sub)steps at once."""

    def __init__(self, table: CommandTable, column: int):
        self.table, self.column = table, int(column)

    def __call__(self, time: float) -> float:
        table = self.table
        return float(table._values[int(table.rows_at(time)), self.column])

    def sample(self, times) -> np.ndarray:
        """Values at ``times`` [s] (array)."""
        table = self.table
        return table._values[table.rows_at(times), self.column]


def commands_schema(names: Sequence[str]):
    """The ROS 2 message type of ``/hydroplant/commands``: the frame's first ``step`` and one float64 per input,
    named by :func:`sim.run.recorder.field_name` (the circuit names in order are in the channel's metadata)."""
    from sim.io.mcap_log import flat_schema
    from sim.run.recorder import field_name

    fields = {"step": "First physics step of the frame [-] (integer valued)"}
    for name in names:
        key = field_name(name)
        if key in fields:
            raise ValueError(f"two inputs are both logged as field {key!r}; rename one (e.g. {name!r})")
        fields[key] = f"Command of {name} over the frame (valve [-], pump [rev/s])"
    return flat_schema("hydroplant_msgs/msg/Commands", fields), list(fields)


def table_from_log(log, dt: float) -> CommandTable:
    """The :class:`CommandTable` of a log (``read_log``) written by ``hydroplant play`` (topic
    :data:`COMMANDS_TOPIC`; the circuit names in its first message's order from the run metadata)."""
    import json

    from sim.io.mcap_file import RUN_METADATA

    meta = log.metadata.get(RUN_METADATA, {})
    if COMMANDS_TOPIC not in log or "command_inputs" not in meta:
        raise ValueError(f"{log.path}: no operator commands ({COMMANDS_TOPIC}); it was not written by 'hydroplant play'")
    names = json.loads(meta["command_inputs"])
    topic = log.topic(COMMANDS_TOPIC)
    from sim.run.recorder import field_name

    steps = topic["step"].astype(np.int64)
    values = np.column_stack([topic[field_name(n)] for n in names]) if names else np.zeros((len(steps), 0))
    return CommandTable(names, dt, steps=steps, values=values)


__all__ = ["COMMANDS_TOPIC", "CommandTable", "HeldInput", "commands_schema", "table_from_log"]
