"""Parameter metadata of the component dataclasses, their validation, and the packing of parameter tables.

Every component field is declared with :func:`param` (unit and allowed range in the field's metadata);
:func:`check_number` validates a value against it with a one-line message naming where it came from;
:func:`table` packs per-branch (or per-component) columns into the float table a compiled law reads,
in the order of the law's named columns.

Example
-------
>>> from dataclasses import dataclass
>>> @dataclass(frozen=True, kw_only=True)
... class Leak:
...     conductance: float = param("m^3/(s*Pa)", low=0.0, high=1e-6)
>>> table(("conductance",), 1, conductance=[1e-9]).shape
(1, 1)
"""

from __future__ import annotations

import math
from dataclasses import MISSING, field

import numpy as np


class CircuitError(ValueError):
    """A circuit or scenario file is wrong; the message names file, component and field."""


def param(unit: str, *, low=None, high=None, low_open=True, default=MISSING, choices=None):
    """A dataclass field with its unit and allowed range ``(low, high]`` (``[low, high]`` if not ``low_open``)."""
    return field(default=default, metadata={"unit": unit, "low": low, "high": high, "low_open": low_open, "choices": choices})


def tables_param(unit: str):
    """A dataclass field holding named knot tables, written in a circuit file as a TOML table of name = [[x, y], …]
    (e.g. a valve's area table per metering edge); ``unit`` names the units of x and y.  Stored as a tuple of
    (name, ((x, y), …)) pairs, empty by default; the component's ``check`` validates names and knots."""
    return field(default=(), metadata={"unit": unit, "low": None, "high": None, "low_open": True, "choices": None,
                                       "tables": True})


def describe_range(meta) -> str:
    """Human text of a field's allowed range, e.g. '(0, 1] m'."""
    if meta.get("tables"):
        return f"a table of name = [[x, y], ...] ({meta['unit']})"
    if meta["choices"]:
        return "one of " + ", ".join(repr(c) for c in meta["choices"])
    low = "-inf" if meta["low"] is None else f"{meta['low']:g}"
    high = "inf" if meta["high"] is None else f"{meta['high']:g}"
    left = "(" if meta["low_open"] or meta["low"] is None else "["
    return f"{left}{low}, {high}] {meta['unit']}".rstrip()


def check_number(value, meta, where: str) -> float:
    """Validate one numeric value against a field's range; raise CircuitError naming ``where``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CircuitError(f"{where}: expected a number in {describe_range(meta)}, got {value!r}")
    try:
        value = float(value)
    except OverflowError:
        raise CircuitError(f"{where}: {value!r} is outside the allowed range {describe_range(meta)}") from None
    low, high = meta["low"], meta["high"]
    ok = math.isfinite(value) or (value == math.inf and high is not None and high >= 1e12)
    if ok and low is not None:
        ok = value > low if meta["low_open"] else value >= low
    if ok and high is not None and value != math.inf:
        ok = value <= high
    if not ok:
        hint = ""
        if high is not None and math.isfinite(value) and value > high and meta["unit"] in ("m", "m^2", "m^3"):
            hint = " (SI units: metres, not millimetres)"
        raise CircuitError(f"{where}: {value!r} is outside the allowed range {describe_range(meta)}{hint}")
    return value


def table(columns: tuple, count: int, **values) -> np.ndarray:
    """The float64 table, shape (count, len(columns)), whose column j holds ``values[columns[j]]``.

    ``values`` must name exactly the ``columns`` (a law's named layout); each value is a scalar or has ``count``
    entries.  Raises ValueError for a missing or unknown name, so a layout and its packing cannot drift apart.
    """
    if set(values) != set(columns):
        raise ValueError(f"table columns {sorted(values)} do not match the layout {list(columns)}")
    out = np.empty((count, len(columns)))
    for j, name in enumerate(columns):
        out[:, j] = np.broadcast_to(np.asarray(values[name], float), (count,))
    return out
