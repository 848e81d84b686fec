"""Proportional 4/3 directional control valve: first- or second-order spool, four metering edges (orifice law),
centre type.

Spool s ∈ [−1, 1] follows its command u clipped to [−1, 1], either through a first-order lag τ·ds/dt = u − s
(proportional valves) or as a mass–spring–damper s̈ + 2ζω·ṡ + ω²·s = ω²·u (servo valves, ω and ζ from the maker's
Bode plot), advanced exactly over a step h with the command held (:func:`spool_step`, :func:`valve_step`; the
transitions of :mod:`hydraulics.components.dynamics`); a second-order spool that reaches ±1 stops there.  s > 0 opens
P→A and B→T, s < 0 opens P→B and A→T; each edge opens linearly beyond the overlap ε,
y = clip((s − ε)/(1 − ε), 0, 1) (:func:`metering_opening`), and its flow is the orifice law
(:mod:`hydraulics.components.orifice`) at area A_leak + y·A_max.  Open and tandem centres add passages of
area y_c·A_centre with y_c = clip(1 − |s|/max(ε, 0.1), 0, 1) (:func:`centre_opening`).  With rigid oil a
metered actuator's force is F_d − R·v·|v| (:func:`metered_actuator_force`; Merritt §5.2).

Packing: the spool table, columns :data:`COLUMNS` (:func:`pack`); the edges are orifice branches.

Example
-------
>>> metering_opening(0.62, 0.05)
0.6
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._jit import clip, kernel, maximum
from .dynamics import second_order_transition
from .metering import CHARACTERISTICS, check_edge_tables
from .parameters import param, table, tables_param


@dataclass(frozen=True, kw_only=True)
class Valve43:
    """Proportional 4/3 directional control valve (ports P, T, A, B).

    Spool s ∈ [−1, 1] follows its command through a first-order lag.  s > 0
    opens P→A and B→T, s < 0 opens P→B and A→T; each metering edge opens
    linearly beyond the overlap.  Centre: ``closed`` (all blocked but leakage),
    ``open`` (P, T, A, B all connected at s = 0), ``tandem`` (P→T open, A and B
    blocked at s = 0).  An LS port (optional) is connected to the work port being fed.
    """

    max_area: float = param("m^2", low=0.0, high=0.01)
    """Area of each metering edge fully open [m²]."""
    centre: str = param("-", default="closed", choices=("closed", "open", "tandem"))
    """Centre type."""
    centre_area: float = param("m^2", low=0.0, high=0.01, low_open=False, default=0.0)
    """Area of the centre passages at s = 0 [m²] (open/tandem)."""
    overlap: float = param("-", low=0.0, high=0.5, low_open=False, default=0.05)
    """Dead band of each edge as a fraction of spool travel [-]."""
    leakage_area: float = param("m^2", low=0.0, high=1e-5, low_open=False, default=1e-9)
    """Area of every edge when closed (spool clearance) [m²]."""
    time_constant: float = param("s", low=0.0, high=10.0, low_open=False, default=0.03)
    """First-order spool time constant τ [s]; 0 = ideal spool."""
    dynamics: str = param("-", default="first_order", choices=("first_order", "second_order"))
    """Spool model: first-order lag (``time_constant``) or second order (``natural_frequency``, ``damping_ratio``)."""
    natural_frequency: float = param("rad/s", low=0.0, high=1e5, default=250.0)
    """Second order: ω [rad/s] (the 90° phase frequency of the valve's Bode plot)."""
    damping_ratio: float = param("-", low=0.0, high=100.0, low_open=False, default=0.7)
    """Second order: ζ [-]."""
    discharge_coefficient: float = param("-", low=0.0, high=1.0, default=0.7)
    """C_d [-]."""
    ls_area: float = param("m^2", low=0.0, high=0.01, default=2e-6)
    """With the optional port LS (load-sensing section): area of the passages A→LS (opening with s > 0) and B→LS
    (s < 0) fully open [m²]; they open linearly beyond the overlap whatever ``metering`` says, so the LS port sees
    the work port being fed from the overlap on."""
    metering: str = param("-", default="linear", choices=CHARACTERISTICS)
    """Area against spool travel of the metering edges (:mod:`hydraulics.components.metering`): linear beyond the
    overlap, exponential (``metering_exponent``) or tabulated per edge (``area_table``)."""
    metering_exponent: float = param("-", low=-30.0, high=30.0, low_open=False, default=3.0)
    """Exponential edges: exponent a of A_max·(e^(a·y) − 1)/(e^a − 1) [-] (a > 0 progressive, a < 0 degressive)."""
    area_table: tuple = tables_param("-, m^2")
    """Tabulated edges: per metering edge (``"P-A"``, ``"B-T"``, ``"P-B"``, ``"A-T"``) its knots
    [[travel, area], …], travel along the edge's opening direction in [−1, 1] [-], area above leakage [m²]
    (monotone C¹ interpolation, overlap included); an edge without a table stays linear."""
    PORTS = ("P", "T", "A", "B")
    OPTIONAL_PORTS = ("LS",)
    STATES = ("spool", "spool_rate")
    """The spool's position and (second order only) its rate."""
    STATE_UNITS = ("-", "1/s")
    METERING_EDGES = ("P-A", "B-T", "P-B", "A-T")
    """The edges the spool meters (a valve kind declares them: the network builds a valve's orifice branches from
    :meth:`edges`, and its spool from the fields ``time_constant``, ``overlap``, ``dynamics``)."""
    COMMAND_RANGE = (-1.0, 1.0)
    """Allowed spool command [-]."""

    def edges(self, ports) -> list:
        """The valve's orifice passages for the connected ``ports``, in branch order: tuples (name, from port,
        to port, direction sign (+1 opens with s > 0, −1 with s < 0, 0 a centre passage), leakage area, metered area
        fully open, centre area [m²], metering edge name or None)."""
        leak, full = self.leakage_area, self.max_area
        out = [(edge, edge[0], edge[2:], sign, leak, full, 0.0, edge)
               for edge, sign in (("P-A", 1), ("B-T", 1), ("P-B", -1), ("A-T", -1))]
        if "LS" in ports:  # a load-sensing section: the LS port sees the work port the spool feeds
            out += [("A-LS", "A", "LS", 1, 0.0, self.ls_area, 0.0, None), ("B-LS", "B", "LS", -1, 0.0, self.ls_area, 0.0, None)]
        return out + self.centre_passages()

    def centre_passages(self) -> list:
        """The open and tandem centres' passages (as :meth:`edges`): P-T, and for an open centre A-T and B-T."""
        out = []
        if self.centre in ("open", "tandem"):
            out.append(("P-T", "P", "T", 0, 0.0, 0.0, self.centre_area, None))
        if self.centre == "open":
            out += [("A-T(centre)", "A", "T", 0, 0.0, 0.0, self.centre_area, None),
                    ("B-T(centre)", "B", "T", 0, 0.0, 0.0, self.centre_area, None)]
        return out

    def check(self, where: str) -> None:
        """Area tables name metering edges and go with ``metering = "table"`` (:func:`~hydraulics.components.metering.check_edge_tables`)."""
        check_edge_tables(self, where)

@kernel
def spool_step(spool, command, tau, dt):
    """Spool position [-] after ``dt`` [s] of τ·ds/dt = u − s from ``spool`` with ``command`` u held; τ = 0: s = u."""
    decay = math.exp(-dt / tau) if tau > 0.0 else 0.0
    return command + (spool - command) * decay


@kernel
def valve_step(row, spool, rate, command, dt):
    """Spool position [-] and rate [1/s] after ``dt`` [s] with ``command`` u ∈ [−1, 1] held, from ``spool`` and
    ``rate``: the first-order lag (rate 0) or the second-order spool of ``row`` (columns :data:`COLUMNS`), stopped
    at ±1."""
    if row[V_ORDER] == 1.0:
        return spool_step(spool, command, row[V_TAU], dt), 0.0
    f11, f12, f21, f22 = second_order_transition(row[V_OMEGA], row[V_ZETA], dt)
    s = command + f11 * (spool - command) + f12 * rate
    r = f21 * (spool - command) + f22 * rate
    if s > 1.0:
        return 1.0, 0.0
    if s < -1.0:
        return -1.0, 0.0
    return s, r


@kernel
def metering_opening(spool, overlap):
    """Opening fraction [0, 1] of an edge that opens for positive spool: clip((s − ε)/(1 − ε), 0, 1)."""
    return clip((spool - overlap) / (1.0 - overlap), 0.0, 1.0)


@kernel
def centre_opening(spool, overlap):
    """Opening fraction of an open/tandem centre passage: 1 at s = 0, closed at |s| ≥ max(ε, 0.1)."""
    return clip(1.0 - abs(spool) / maximum(overlap, 0.1), 0.0, 1.0)


@kernel
def metered_actuator_force(direction, area_in, area_out, orifice_in, orifice_out, supply_pressure, tank_pressure, density,
                           ambient_pressure):
    """Valve-metered actuator with rigid oil (Merritt §5.2, quasi-static): F(v) = F_d − R·v·|v| [N or N·m].

    With the metering edges P → inlet chamber (effective area ``orifice_in`` = C_d·a_in [m²]) and outlet chamber → T
    (``orifice_out``), piston areas A_in, A_out [m²] (D/2π [m³/rad] for a motor) of the commanded ``direction``
    (+1 extending: A_in = A_cap; −1 retracting: A_in = A_rod) and the ambient pressure p_a [Pa] on the rod side of
    the piston (as :func:`hydraulics.components.cylinder.pressure_force`):

        F_d = direction·((p_s − p_a)·A_in − (p_t − p_a)·A_out),
        R = (ρ/2)·(A_in³/(C_d·a_in)² + A_out³/(C_d·a_out)²).

    Returns (F_d [N], R [N·s²/m²]); R is inf where an edge is shut.  Pressures p_s, p_t [Pa], ρ [kg/m³].
    """
    # (products, not powers: compiled and Python runs then round alike)
    resistance = 0.5 * density * (area_in * area_in * area_in / (orifice_in * orifice_in)
                                  + area_out * area_out * area_out / (orifice_out * orifice_out))
    drive = direction * ((supply_pressure - ambient_pressure) * area_in - (tank_pressure - ambient_pressure) * area_out)
    return drive, resistance


@kernel
def metering_direction(spool, overlap):
    """Metering direction [-] of a spool position s: sign(s) while an edge is open beyond the overlap ε, else 0
    (+1: P feeds the cap side / motor port a)."""
    if metering_opening(abs(spool), overlap) > 0.0:
        return 1.0 if spool > 0.0 else (-1.0 if spool < 0.0 else 0.0)
    return 0.0 if spool == spool else spool


@kernel
def displaced_rate(direction, extend_area, retract_area):
    """Flow the valve meters per unit actuator velocity with rigid oil [m² | m³/rad]: A_cap (D/2π) extending,
    −A_rod retracting, 0 closed (``direction`` from :func:`metering_direction`)."""
    if direction > 0.0:
        return extend_area
    if direction < 0.0:
        return -retract_area
    return 0.0


COLUMNS = ("time_constant", "overlap", "order", "omega", "zeta", "command_low")
"""Spool table: time constant τ [s], overlap ε [-], spool order (1 or 2), natural frequency ω [rad/s], damping ratio
ζ [-], lowest command [-] (the valve kind's ``COMMAND_RANGE``; the highest is 1 for every kind)."""
V_TAU, V_OVERLAP, V_ORDER, V_OMEGA, V_ZETA, V_LOW = range(len(COLUMNS))


def pack(model) -> np.ndarray:
    """The spool table of a :class:`~hydraulics.network.NetworkModel`, columns :data:`COLUMNS`."""
    return table(COLUMNS, len(model.valve_names), time_constant=model.valve_time_constant, overlap=model.valve_overlap,
                 order=np.where(model.valve_rate_offset >= 0, 2.0, 1.0), omega=model.valve_omega,
                 zeta=model.valve_zeta, command_low=model.valve_command_low)
