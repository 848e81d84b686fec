"""From a device's axes to valve commands: dead band, expo, inversion, and the standard excavator patterns.

A command source reports named axes in [−1, 1] (:mod:`sim.live.protocol`): ``left_x``, ``left_y``, ``right_x``,
``right_y`` (sticks; **x + = pushed right, y + = pushed forward, away from the operator**), ``l2``, ``r2``
(triggers).  A scenario's ``[mapping]`` section says which axis drives which valve and how:

    [mapping]
    preset = "iso"                  # "iso" | "sae": the excavator patterns below
    dead_band = 0.1                 # [-] of the preset's axes
    expo = 0.3                      # [-] of the preset's axes
    [mapping.axes]                  # one entry per axis (replaces the preset's entry for that axis)
    l2 = { valve = "hammer_valve", dead_band = 0.05, expo = 0.0, invert = false }

Per axis, with u the axis value clipped to [−1, 1], b the dead band and e the expo:

    s = (|u| − b) / (1 − b)  where |u| > b, else 0          (dead band: 0 inside, continuous at its edge)
    y = sign(u) · ((1 − e)·s + e·s³)                         (expo: fine control near centre, y(±1) = ±1)
    command = −y if invert else y

y is odd, monotone in u and ±1 at ±1 for every b in [0, 0.9] and e in [0, 1].  Several axes on one valve add, then
clip to [−1, 1].  Names a source gives that are the circuit's valves or pumps pass through unchanged (a program or a
Foxglove client commanding valves directly); other names are not axes of the mapping and are ignored.

The excavator patterns (valve names of ``models/excavator``: ``<function>_valve``; spool sign of that scene:
+1 = boom up, stick in (crowd), bucket curl, swing left (counter-clockwise seen from above)):

==========  ===========================  ===========================
axis        ISO (ISO 10968, SAE J1177)   SAE (SAE J1814)
==========  ===========================  ===========================
left_x      swing: right = swing right   swing: right = swing right
left_y      stick: forward = stick out   boom: forward = boom down
right_x     bucket: left = curl,         bucket: left = curl,
            right = dump                 right = dump
right_y     boom: forward = boom down    stick: forward = stick out
==========  ===========================  ===========================

Every preset axis is therefore inverted against the scene's spool sign (forward = −1 on boom and stick, right = −1
on swing and bucket).  A scene whose valves have other names or senses gives its own ``[mapping.axes]``.

Example
-------
>>> m = Mapping.preset("iso", dead_band=0.0, expo=0.0)
>>> m.apply({"right_y": 1.0})            # right stick forward: boom down
{'boom_valve': -1.0}
>>> Mapping.preset("sae", dead_band=0.0, expo=0.0).apply({"right_y": 1.0})   # SAE: the right stick is the stick
{'stick_valve': -1.0}
"""

from __future__ import annotations

import math
from collections.abc import Mapping as MappingABC
from dataclasses import dataclass, field

from sim.io.errors import ScenarioError

AXES = ("left_x", "left_y", "right_x", "right_y", "l2", "r2")
"""The device axes a mapping may name (sticks: x + right, y + forward; triggers 0..1 or −1..1 as the device gives)."""
DEAD_BAND_RANGE = (0.0, 0.9)  # [-], closed
EXPO_RANGE = (0.0, 1.0)  # [-], closed
DEFAULT_DEAD_BAND = 0.1  # [-]: a worn gamepad stick rests within ±0.1
DEFAULT_EXPO = 0.3  # [-]

# function -> (axis, invert) of each pattern; the valve is "<function>_valve"
PRESETS = {
    "iso": {"swing": ("left_x", True), "stick": ("left_y", True), "bucket": ("right_x", True), "boom": ("right_y", True)},
    "sae": {"swing": ("left_x", True), "boom": ("left_y", True), "bucket": ("right_x", True), "stick": ("right_y", True)},
}
"""The excavator control patterns: ISO 10968 / SAE J1177 (``iso``) and SAE J1814 (``sae``), boom and stick on swapped
hands (see the module docstring)."""


class MappingError(ScenarioError):
    """A ``[mapping]`` section is wrong; the message names the field and the allowed values."""


@dataclass(frozen=True)
class AxisMap:
    """How one device axis drives one valve."""

    valve: str
    """Circuit valve (or pump) the axis drives."""
    dead_band: float = DEFAULT_DEAD_BAND
    """Half-width of the zero band around the centre [-], in [0, 0.9]."""
    expo: float = DEFAULT_EXPO
    """Weight of the cubic term [-], in [0, 1]: 0 linear, 1 pure cubic."""
    invert: bool = False
    """Negate the command (the valve's + sense opposes the axis's)."""

    def __call__(self, u: float) -> float:
        """The command [-] for axis value ``u`` (see the module docstring)."""
        return shape(u, self.dead_band, self.expo, self.invert)


def shape(u: float, dead_band: float, expo: float, invert: bool = False) -> float:
    """Dead band, then expo, then inversion of an axis value ``u`` (clipped to [−1, 1]); odd and monotone in u,
    0 for |u| <= ``dead_band``, ±1 at u = ±1."""
    u = min(1.0, max(-1.0, float(u))) if math.isfinite(u) else 0.0
    magnitude = abs(u)
    if magnitude <= dead_band:
        return 0.0
    s = (magnitude - dead_band) / (1.0 - dead_band)
    y = (1.0 - expo) * s + expo * s * s * s
    y = math.copysign(min(y, 1.0), u)
    return -y if invert else y


@dataclass(frozen=True)
class Mapping:
    """Axis name → :class:`AxisMap`; :meth:`apply` turns a source's values into circuit commands."""

    axes: dict = field(default_factory=dict)
    preset_name: str | None = None

    @classmethod
    def preset(cls, name: str, *, dead_band: float = DEFAULT_DEAD_BAND, expo: float = DEFAULT_EXPO,
               valves: MappingABC | None = None) -> "Mapping":
        """The pattern ``name`` (``"iso"`` or ``"sae"``); ``valves`` renames functions' valves
        (default ``"<function>_valve"``)."""
        if name not in PRESETS:
            raise MappingError(f"preset {name!r} is not one of {sorted(PRESETS)}")
        valves = dict(valves or {})
        axes = {axis: AxisMap(valves.get(function, f"{function}_valve"), dead_band, expo, invert)
                for function, (axis, invert) in PRESETS[name].items()}
        return cls(axes, name)

    def apply(self, values: MappingABC, passthrough=()) -> dict:
        """Circuit commands from a source's ``values``: mapped axes (summed per valve, clipped to [−1, 1]) and the
        names in ``passthrough`` (the circuit's valves and pumps) as they are; other names are dropped."""
        out: dict = {}
        summed: dict = {}
        for name, value in values.items():
            axis = self.axes.get(name)
            if axis is not None:
                summed[axis.valve] = summed.get(axis.valve, 0.0) + axis(value)
            elif name in passthrough:
                out[name] = float(value)
        for valve, value in summed.items():
            out[valve] = min(1.0, max(-1.0, value))
        return out

    def targets(self) -> set:
        """The circuit inputs the mapping drives."""
        return {a.valve for a in self.axes.values()}


def _number(table, key, where, bounds, default):
    value = table.get(key, default)
    low, high = bounds
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (low <= float(value) <= high):
        raise MappingError(f"{where}: field '{key}': {value!r} is not a number in [{low:g}, {high:g}]")
    return float(value)


def parse_mapping(table, where: str) -> Mapping | None:
    """The :class:`Mapping` of a scenario's ``[mapping]`` table (None when there is none); ``where`` names the file.

    Raises :class:`MappingError` naming the file, the field and the allowed values.
    """
    if table is None:
        return None
    if not isinstance(table, dict):
        raise MappingError(f"{where}: [mapping] must be a table")
    unknown = sorted(set(table) - {"preset", "dead_band", "expo", "axes", "valves"})
    if unknown:
        raise MappingError(f"{where}: unknown field(s) in [mapping]: {unknown}; allowed: "
                           "['axes', 'dead_band', 'expo', 'preset', 'valves']")
    w = f"{where}, [mapping]"
    dead_band = _number(table, "dead_band", w, DEAD_BAND_RANGE, DEFAULT_DEAD_BAND)
    expo = _number(table, "expo", w, EXPO_RANGE, DEFAULT_EXPO)
    valves = table.get("valves", {})
    if not isinstance(valves, dict) or not all(isinstance(v, str) for v in valves.values()) or \
            set(valves) - {"boom", "stick", "bucket", "swing"}:
        raise MappingError(f"{w}: field 'valves': a table of function = valve name, functions boom, stick, bucket, swing")
    preset = table.get("preset")
    if preset is not None:
        if preset not in PRESETS:
            raise MappingError(f"{w}: field 'preset': {preset!r} is not one of {sorted(PRESETS)}")
        mapping = Mapping.preset(preset, dead_band=dead_band, expo=expo, valves=valves)
    else:
        mapping = Mapping({}, None)
    axes = dict(mapping.axes)
    entries = table.get("axes", {})
    if not isinstance(entries, dict):
        raise MappingError(f"{w}: field 'axes': a table of axis = {{ valve = ..., dead_band = ..., expo = ..., invert = ... }}")
    for axis, spec in entries.items():
        aw = f"{where}, [mapping.axes.{axis}]"
        if axis not in AXES:
            raise MappingError(f"{where}, [mapping.axes]: axis {axis!r} is not one of {list(AXES)}")
        if not isinstance(spec, dict) or not isinstance(spec.get("valve"), str):
            raise MappingError(f"{aw}: a table with 'valve' (a circuit valve or pump name) is required")
        extra = sorted(set(spec) - {"valve", "dead_band", "expo", "invert"})
        if extra:
            raise MappingError(f"{aw}: unknown field(s) {extra}; allowed: ['dead_band', 'expo', 'invert', 'valve']")
        invert = spec.get("invert", False)
        if not isinstance(invert, bool):
            raise MappingError(f"{aw}: field 'invert': expected true or false, got {invert!r}")
        axes[axis] = AxisMap(spec["valve"], _number(spec, "dead_band", aw, DEAD_BAND_RANGE, dead_band),
                             _number(spec, "expo", aw, EXPO_RANGE, expo), invert)
    return Mapping(axes, preset)


def check_targets(mapping: Mapping, inputs, where: str) -> None:
    """Refuse a mapping that drives a name the circuit has no valve or pump for (``inputs``: the circuit's names)."""
    for axis, target in mapping.axes.items():
        if target.valve not in inputs:
            raise MappingError(f"{where}, [mapping]: axis {axis!r} drives {target.valve!r}, which is no valve or pump of "
                               f"the circuit; its valves and pumps: {sorted(inputs)}")


__all__ = ["AXES", "PRESETS", "AxisMap", "Mapping", "MappingError", "check_targets", "parse_mapping", "shape"]
