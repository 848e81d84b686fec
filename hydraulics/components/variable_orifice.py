"""Variable orifice: an orifice whose opening is commanded (a proportional throttle, a 2/2 proportional valve).

Its opening s ∈ [0, 1] follows the command u (a scenario input or a controller, by the component's name; commands
below 0 close it) through the spool dynamics of the 4/3 valve (:mod:`hydraulics.components.valve_4_3`: ideal with
``time_constant = 0``, a first-order lag, or a second-order spool), and its area is

    A(s) = A_leak + A_max·y,   y = clip((s − ε)/(1 − ε), 0, 1)

with the edge characteristics of :mod:`hydraulics.components.metering` (linear, exponential, or a table of the edge
``"a-b"``).  The flow from ``a`` to ``b`` is the orifice law (:mod:`hydraulics.components.orifice`) through A(s),
either direction.  States: the opening (and its rate for a second-order spool), logged on
``/hydroplant/valves/<name>`` as a valve's spool.

References: Hopsan component library, *HydraulicVariableOrifice* (commanded opening times a full area); MathWorks,
Simscape Fluids, variable orifice block (isothermal liquid).

Limitations: no flow forces on the throttle; the opening does not depend on the pressures.

Example
-------
>>> throttle = VariableOrifice(max_area=2e-5)
>>> [edge[:4] for edge in throttle.edges(("a", "b"))]
[('a-b', 'a', 'b', 1)]
"""

from __future__ import annotations

from dataclasses import dataclass

from .metering import CHARACTERISTICS, check_edge_tables
from .parameters import param, tables_param


@dataclass(frozen=True, kw_only=True)
class VariableOrifice:
    """Throttle with a commanded opening (ports a, b; the command, in [0, 1], by the component's name)."""

    max_area: float = param("m^2", low=0.0, high=0.01)
    """Open area at full opening (above leakage) [m²]."""
    leakage_area: float = param("m^2", low=0.0, high=1e-5, low_open=False, default=1e-9)
    """Area when closed [m²]."""
    overlap: float = param("-", low=0.0, high=0.5, low_open=False, default=0.0)
    """Dead band of the opening [-]: no area below this command."""
    discharge_coefficient: float = param("-", low=0.0, high=1.0, default=0.7)
    """C_d [-]."""
    time_constant: float = param("s", low=0.0, high=10.0, low_open=False, default=0.0)
    """First-order lag of the opening τ [s]; 0: the opening is the command."""
    dynamics: str = param("-", default="first_order", choices=("first_order", "second_order"))
    """Opening model: first-order lag (``time_constant``) or second order (``natural_frequency``, ``damping_ratio``)."""
    natural_frequency: float = param("rad/s", low=0.0, high=1e5, default=250.0)
    """Second order: ω [rad/s]."""
    damping_ratio: float = param("-", low=0.0, high=100.0, low_open=False, default=0.7)
    """Second order: ζ [-]."""
    metering: str = param("-", default="linear", choices=CHARACTERISTICS)
    """Area against opening (:mod:`hydraulics.components.metering`): linear, exponential or tabulated."""
    metering_exponent: float = param("-", low=-30.0, high=30.0, low_open=False, default=3.0)
    """Exponential opening: exponent a [-]."""
    area_table: tuple = tables_param("-, m^2")
    """Tabulated opening: ``{"a-b" = [[opening, area], …]}``, opening in [0, 1] [-], area above leakage [m²]."""
    PORTS = ("a", "b")
    STATES = ("spool", "spool_rate")
    """The opening (logged as the valve's spool) and (second order only) its rate."""
    STATE_UNITS = ("-", "1/s")
    METERING_EDGES = ("a-b",)
    """Its one metering edge (a valve kind: see :class:`~hydraulics.components.valve_4_3.Valve43`)."""
    COMMAND_RANGE = (0.0, 1.0)
    """Allowed opening command [-]."""

    def edges(self, ports) -> list:
        """The orifice passage a → b, as :meth:`hydraulics.components.valve_4_3.Valve43.edges` lists a valve's."""
        del ports
        return [("a-b", "a", "b", 1, self.leakage_area, self.max_area, 0.0, "a-b")]

    def check(self, where: str) -> None:
        """The area table, if any, is the edge ``"a-b"``'s, within [0, 1], and goes with ``metering = "table"``."""
        check_edge_tables(self, where)
