"""Metering characteristics of a valve edge: open area against spool travel, linear, exponential or tabulated.

A valve's edge opens with the spool travel x along its direction (x = +s for an edge that opens with a positive
spool, −s for one that opens with a negative spool; x ∈ [−1, 1]).  Its open area is the leakage area plus

* ``linear``:       A_max·y,  y = clip((x − ε)/(1 − ε), 0, 1)  (overlap ε; :func:`hydraulics.components.valve_4_3.metering_opening`);
* ``exponential``:  A_max·(e^(a·y) − 1)/(e^a − 1)  (:func:`shaped_opening`; a > 0 a progressive edge with fine
  metering near closing, a < 0 a degressive one; a → 0 is the linear edge);
* ``table``:        A(x) interpolated in the edge's table of knots (x_k, A_k) by the monotone piecewise cubic
  Hermite interpolant of Fritsch and Carlson (PCHIP: C¹, no overshoot between knots, monotone where the data
  are; :func:`knot_slopes`, the slopes scipy's ``PchipInterpolator`` takes), held at A_0 below the first knot
  and at A_last beyond the last (:func:`table_area`).
  The table carries the whole characteristic, overlap included: the valve's ``overlap`` does not apply to it.

An edge's characteristic is one row of :data:`COLUMNS` (the shape exponent a, 0 for linear; the first knot and
the number of knots of its table in the network's knot table, :data:`KNOT_COLUMNS`; 0 knots for a law).

References: F. N. Fritsch, R. E. Carlson, *Monotone piecewise cubic interpolation*, SIAM J. Numer. Anal. 17 (1980)
238–246; MathWorks, Simscape Fluids, spool orifice block (isothermal liquid), tabulated area parametrisation;
Hopsan component library, *Hydraulic43Valve* (linear edges with overlap).

Limitations: the area depends on the spool alone (no flow forces); a table's slope beyond its ends is zero.

Example
-------
>>> import numpy as np
>>> knots = table_knots([0.1, 0.5, 1.0], [0.0, 1e-5, 4e-5])
>>> round(table_area(knots, 0, 3, 0.5) * 1e6, 3), table_area(knots, 0, 3, 0.0)  # at a knot; below the first
(10.0, 0.0)
>>> round(shaped_opening(0.5, 3.0), 4)  # a progressive edge half open passes 18 % of its full area
0.1824
"""

from __future__ import annotations

import math
from dataclasses import fields

import numpy as np

from .._jit import kernel

CHARACTERISTICS = ("linear", "exponential", "table")
"""The ``metering`` choices of a valve."""
COLUMNS = ("shape", "knot_first", "knot_count")
"""An edge's characteristic: exponent a of the exponential edge [-] (0: linear), first row of its table in the knot
table and its number of knots (0: no table)."""
M_SHAPE, M_FIRST, M_COUNT = range(len(COLUMNS))
KNOT_COLUMNS = ("travel", "area", "slope")
"""Knot table: spool travel x_k [-], area A_k [m²] and the interpolant's slope dA/dx at the knot [m²]."""
K_TRAVEL, K_AREA, K_SLOPE = range(len(KNOT_COLUMNS))
TABLE_AREA_LIMIT = 0.01
"""Largest area a table may give [m²] (as a valve's ``max_area``)."""


@kernel
def shaped_opening(opening, shape):
    """Area fraction [0, 1] of an edge at linear opening y ∈ [0, 1]: (e^(a·y) − 1)/(e^a − 1) for the exponent
    ``shape`` a ≠ 0, y for a = 0."""
    if shape == 0.0:
        return opening
    return math.expm1(shape * opening) / math.expm1(shape)


@kernel
def table_area(knots, first, count, travel):
    """Area [m²] of a tabulated edge at spool travel ``travel`` x: the cubic Hermite interpolant of knots
    ``first`` … ``first + count − 1`` of ``knots`` (columns :data:`KNOT_COLUMNS`), held at the end values outside.

    On [x_k, x_k+1] with t = (x − x_k)/Δ: A = h00·A_k + h10·Δ·m_k + h01·A_k+1 + h11·Δ·m_k+1,
    h00 = (1 + 2t)(1 − t)², h10 = t(1 − t)², h01 = t²(3 − 2t), h11 = t²(t − 1).
    """
    last = first + count - 1
    if travel <= knots[first, K_TRAVEL]:
        return knots[first, K_AREA]
    if travel >= knots[last, K_TRAVEL]:
        return knots[last, K_AREA]
    k = first
    while knots[k + 1, K_TRAVEL] < travel:
        k += 1
    x0, x1 = knots[k, K_TRAVEL], knots[k + 1, K_TRAVEL]
    width = x1 - x0
    t = (travel - x0) / width
    u = 1.0 - t
    return ((1.0 + 2.0 * t) * u * u * knots[k, K_AREA] + t * u * u * width * knots[k, K_SLOPE]
            + t * t * (3.0 - 2.0 * t) * knots[k + 1, K_AREA] - t * t * u * width * knots[k + 1, K_SLOPE])


@kernel
def edge_area(row, knots, max_area, travel, opening):
    """Open area above leakage [m²] of an edge with characteristic ``row`` (columns :data:`COLUMNS`) at spool
    travel x = ``travel`` and linear opening y = ``opening`` (overlap applied): A_max·y, A_max·shaped(y) or the
    table's A(x)."""
    if row[M_COUNT] > 0.0:
        return table_area(knots, int(row[M_FIRST]), int(row[M_COUNT]), travel)
    if row[M_SHAPE] == 0.0:
        return max_area * opening
    return max_area * shaped_opening(opening, row[M_SHAPE])


def table_knots(travel, area) -> np.ndarray:
    """Knot rows (columns :data:`KNOT_COLUMNS`) of the table (x_k, A_k): the knots with the PCHIP slopes of
    :func:`knot_slopes`."""
    travel, area = np.asarray(travel, float), np.asarray(area, float)
    return np.column_stack((travel, area, knot_slopes(travel, area)))


def knot_slopes(travel, area) -> np.ndarray:
    """Slopes dA/dx [m²] at the knots of the Fritsch–Carlson monotone cubic through (x_k, A_k), as scipy's
    ``PchipInterpolator`` sets them: with the secants δ_k = ΔA_k/Δx_k, an inner knot takes 0 where δ changes sign
    or vanishes, else the weighted harmonic mean (w₁ + w₂)/(w₁/δ_{k−1} + w₂/δ_k), w₁ = 2Δx_k + Δx_{k−1},
    w₂ = Δx_k + 2Δx_{k−1}; an end takes the one-sided three-point slope ((2Δx₀ + Δx₁)·δ₀ − Δx₀·δ₁)/(Δx₀ + Δx₁),
    0 if its sign differs from δ₀'s, 3δ₀ if it exceeds that where δ changes sign; two knots: the secant."""
    x, a = np.asarray(travel, float), np.asarray(area, float)
    h, delta = np.diff(x), np.diff(a) / np.diff(x)
    if len(x) == 2:
        return np.full(2, delta[0])
    slopes = np.zeros(len(x))
    w1, w2 = 2.0 * h[1:] + h[:-1], h[1:] + 2.0 * h[:-1]
    same = (np.sign(delta[:-1]) == np.sign(delta[1:])) & (delta[:-1] != 0.0) & (delta[1:] != 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = (w1 + w2) / (w1 / delta[:-1] + w2 / delta[1:])
    slopes[1:-1] = np.where(same, mean, 0.0)
    for end, (h0, h1, d0, d1) in ((0, (h[0], h[1], delta[0], delta[1])), (-1, (h[-1], h[-2], delta[-1], delta[-2]))):
        d = ((2.0 * h0 + h1) * d0 - h0 * d1) / (h0 + h1)
        if np.sign(d) != np.sign(d0):
            d = 0.0
        elif np.sign(d0) != np.sign(d1) and abs(d) > abs(3.0 * d0):
            d = 3.0 * d0
        slopes[end] = d
    return slopes


def check_table(value, where: str) -> tuple:
    """A metering table of a circuit file, ``[[x_0, A_0], [x_1, A_1], …]``, validated: at least two knots, travel
    strictly increasing in [−1, 1], areas in [0, :data:`TABLE_AREA_LIMIT`] m².  Returns ((x_k), (A_k)); raises
    :class:`~hydraulics.components.parameters.CircuitError` naming ``where``."""
    from .parameters import CircuitError  # noqa: PLC0415  (parameters imports nothing of this module)

    shape = "a list of at least two [travel, area] pairs, travel [-] strictly increasing in [-1, 1], area in [0, 0.01] m^2"
    try:
        pairs = [(x, a) for x, a in value]
    except (TypeError, ValueError):
        raise CircuitError(f"{where}: expected {shape}, got {value!r}") from None
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for pair in pairs for v in pair):
        raise CircuitError(f"{where}: expected {shape}, got {value!r}")
    pairs = [(float(x), float(a)) for x, a in pairs]
    travel, area = zip(*pairs) if pairs else ((), ())
    if (len(pairs) < 2 or not all(map(math.isfinite, travel + area))
            or any(b <= a for a, b in zip(travel, travel[1:])) or travel[0] < -1.0 or travel[-1] > 1.0
            or min(area) < 0.0 or max(area) > TABLE_AREA_LIMIT):
        raise CircuitError(f"{where}: expected {shape}, got {value!r}")
    return travel, area


def check_edge_tables(valve, where: str) -> None:
    """A valve's ``area_table`` names only its kind's ``METERING_EDGES``, with travel within its ``COMMAND_RANGE``,
    and is given exactly when ``metering = "table"``; a ``metering_exponent`` off its default goes with
    ``metering = "exponential"`` (elsewhere it would be ignored); raises
    :class:`~hydraulics.components.parameters.CircuitError` naming ``where`` and the field."""
    from .parameters import CircuitError  # noqa: PLC0415

    default_exponent = next(f.default for f in fields(valve) if f.name == "metering_exponent")
    if valve.metering != "exponential" and valve.metering_exponent != default_exponent:
        raise CircuitError(f"{where}, field 'metering_exponent': given with metering = {valve.metering!r}, which does "
                           f"not read it; set metering = \"exponential\"")
    edges, low = type(valve).METERING_EDGES, type(valve).COMMAND_RANGE[0]
    tables = dict(valve.area_table)
    unknown = sorted(set(tables) - set(edges))
    if unknown:
        raise CircuitError(f"{where}, field 'area_table': unknown edge(s) {unknown}; edges: {list(edges)}")
    if tables and valve.metering != "table":
        raise CircuitError(f"{where}, field 'area_table': given with metering = {valve.metering!r}; set metering = \"table\"")
    if valve.metering == "table" and not tables:
        raise CircuitError(f"{where}, field 'area_table': metering = \"table\" needs a table for at least one of {list(edges)}")
    for edge, knots in tables.items():  # ((x_0, A_0), (x_1, A_1), …), travel increasing
        if knots[0][0] < low:
            raise CircuitError(f"{where}, field 'area_table', table '{edge}': travel {knots[0][0]!r} is outside the "
                               f"command range [{low:g}, 1]")


def characteristics(edges) -> tuple[np.ndarray, np.ndarray]:
    """Rows of :data:`COLUMNS` for the edges ``edges`` (pairs (valve parameters, edge name or None for a passage
    that is no metering edge), in branch order) and the knot table they index."""
    rows, knots = np.zeros((len(edges), len(COLUMNS))), [np.zeros((0, len(KNOT_COLUMNS)))]
    first = 0
    for i, (params, edge) in enumerate(edges):
        kind = getattr(params, "metering", "linear") if edge is not None else "linear"
        if kind == "exponential":
            rows[i, M_SHAPE] = params.metering_exponent
        elif kind == "table" and (pairs := dict(params.area_table).get(edge)) is not None:
            table = table_knots(*zip(*pairs))
            rows[i, M_FIRST], rows[i, M_COUNT] = first, len(table)
            knots.append(table)
            first += len(table)
    return rows, np.concatenate(knots)
