"""Direct-acting pressure-relief valve with poppet dynamics: the opening lags the pressure (first order) or
oscillates about it (second order: mass, spring, damping), between the seat and the stop.

The poppet's normalised opening y ∈ [0, 1] (lift / full lift) is driven by the differential pressure
Δp = p_in − p_out through the static characteristic

    z(Δp) = (Δp − p_crack)/(p_full − p_crack),

the opening the spring and the pressure force balance at (0 at the cracking pressure, 1 at full opening).
Its dynamics, with the ``dynamics`` field:

* ``first_order``: τ·ẏ = clip(z, 0, 1) − y;
* ``second_order``: ÿ + 2ζω·ẏ + ω²·y = ω²·z (the force balance m·ẍ + c·ẋ + k·x = A·(Δp − p_crack) divided by
  k·x_full: ω = √(k/m), ζ = c/(2√(k·m))), with inelastic end stops: at y = 0 (seat) and y = 1 (stop) the poppet
  is held and its speed set to zero.

The flow is the orifice law of :mod:`hydraulics.components.orifice` through A(y) = A_leak + A_full·y (either
direction; Q > 0 from inlet to outlet).

**Step.**  Over a step of h with the end pressure's z held (zero-order hold), the linear dynamics are integrated
exactly (:mod:`hydraulics.components.dynamics`): with s = (y, ẏ) and the equilibrium s_z = (z, 0),
s⁺ = s_z + Φ(h)·(s − s_z), Φ = exp(A_y·h); then the end stops clamp y⁺.  y⁺ is affine in z and so in the end pressures: the network's Newton solve sees the
flow at the end of the step, Q(A(y⁺(Δp)), Δp), with its total derivative

    dQ/dΔp = ∂Q/∂Δp + ∂Q/∂A·A_full·(∂y⁺/∂z)/(p_full − p_crack),   ∂y⁺/∂z = 1 − Φ₁₁ (0 where clamped),

so the valve is as stable as a static one at any step and exact for the poppet's own motion whatever h·ω.

States: ``opening`` y [-] and ``opening_rate`` ẏ [1/s] (zero for the first-order poppet), both 0 at rest.
Ports: ``inlet``, ``outlet``.  Packing: one row per valve, columns :data:`COLUMNS` (:meth:`law_row`).

Kink hook (:func:`law_piece`): the poppet on its seat, moving or at its stop, the first-order target clipped, and
the hysteresis band's piece.

**Hysteresis** (``reseat_pressure`` below the cracking pressure): an opened poppet closes at a lower pressure than
it opened, as friction and flow forces make a real one do.  The target is then the play operator of the opening
characteristic, z = clip(z⁻, z_o(Δp), z_o(Δp) + w) with w = (p_crack − p_reseat)/(p_full − p_crack) and z⁻ the
play's output at the start of the step (a state of its own, ``play``, so that a poppet swinging about its target
does not move the target): rising pressure drives the poppet along z_o (cracking at p_crack), falling pressure
along z_o + w (reseating at p_reseat), and in between the target holds (dz/dΔp = 0 there; the band is a piece of
the kink hook).

Limitations: no flow forces, no bounce at the stops.

References: Hopsan component library, *HydraulicPressureReliefValve* (first-order opening with time constant);
H. E. Merritt, *Hydraulic Control Systems*, Wiley 1967, §5 (poppet valve dynamics); MathWorks, Simscape
Fluids, *Pressure Relief Valve (IL)*, opening dynamics.

Example
-------
>>> import numpy as np
>>> from hydraulics.fluid import Fluid
>>> valve = ReliefPoppet(cracking_pressure=1e7, full_open_pressure=1.2e7, area=2e-5, dynamics="second_order",
...                      natural_frequency=300.0, damping_ratio=0.3)
>>> row, ambient = valve.law_row(Fluid()), Fluid().reference_pressure
>>> state = np.zeros(3)
>>> step_end(row, state, 1e-3, ambient + 1.1e7, ambient, 0.0, state)  # halfway open, 1 ms on
>>> 0.0 < state[0] < 0.5 < state[1] * 1e-3
True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._jit import kernel
from .dynamics import first_order_transition, second_order_transition
from .orifice import coefficients as orifice_coefficients
from .orifice import flow_area_derivative as orifice_flow_area_derivative
from .orifice import flow_with_derivative as orifice_flow_with_derivative
from .parameters import CircuitError, param, table

COLUMNS = ("cracking", "span", "area", "leakage", "k", "c", "order", "tau", "omega", "zeta", "play")
"""Row of one valve: cracking pressure [Pa], p_full − p_crack [Pa], full and closed area [m²], orifice-law constants
k, c, dynamics order (1 or 2), time constant τ [s], natural frequency ω [rad/s], damping ratio ζ [-], hysteresis
band w = (p_crack − p_reseat)/(p_full − p_crack) [-]."""
CRACKING, SPAN, AREA, LEAKAGE, K, C, ORDER, TAU, OMEGA, ZETA, PLAY = range(len(COLUMNS))
STATES = ("opening", "opening_rate", "play")
"""The states of one valve: normalised opening y [-], its rate ẏ [1/s], and the hysteresis play's output z [-] (its
memory; 0 without hysteresis)."""
Y, RATE, MEMORY = range(len(STATES))


@kernel
def transition(row, h):
    """Φ(h) = (Φ₁₁, Φ₁₂, Φ₂₁, Φ₂₂) of the poppet's free motion over ``h`` [s] (first order: (e^(−h/τ), 0, 0, 0))."""
    if row[ORDER] == 1.0:
        return first_order_transition(row[TAU], h), 0.0, 0.0, 0.0
    return second_order_transition(row[OMEGA], row[ZETA], h)


@kernel
def play_output(row, memory, dp):
    """The characteristic's output z [-] at the differential pressure ``dp`` [Pa] and its band piece: without
    hysteresis z = z_o = (Δp − p_crack)/span (piece 0); with it (band w > 0) the play operator of its previous output
    ``memory``, z = clip(memory, z_o, z_o + w): on the opening line (0), held inside the band (1), on the reseat line
    (2)."""
    z = (dp - row[CRACKING]) / row[SPAN]
    if row[PLAY] > 0.0:
        if memory > z + row[PLAY]:
            return z + row[PLAY], 2
        if memory > z:
            return memory, 1
    return z, 0


@kernel
def target(row, memory, dp):
    """The opening the pressure drives the poppet to, z [-] (:func:`play_output` from the play's ``memory``), and
    dz/dΔp [1/Pa] (0 inside the hysteresis band); clipped to [0, 1] for the first-order poppet."""
    z, piece = play_output(row, memory, dp)
    if row[ORDER] == 1.0:
        if z <= 0.0:
            return 0.0, 0.0
        if z >= 1.0:
            return 1.0, 0.0
    return z, (0.0 if piece == 1 else 1.0 / row[SPAN])


@kernel
def advance(row, state, h, dp):
    """Opening y⁺ [-], rate ẏ⁺ [1/s] after ``h`` [s] with the differential pressure ``dp`` [Pa] held, and ∂y⁺/∂Δp
    [1/Pa]."""
    y0, r0 = state[Y], state[RATE]
    z, dz = target(row, state[MEMORY], dp)
    f11, f12, f21, f22 = transition(row, h)
    y = z + f11 * (y0 - z) + f12 * r0
    rate = f21 * (y0 - z) + f22 * r0
    slope = (1.0 - f11) * dz
    if y <= 0.0:
        return 0.0, 0.0, 0.0
    if y >= 1.0:
        return 1.0, 0.0, 0.0
    return y, rate, slope


@kernel
def law_piece(row, state, h, p_in, p_out, p_pilot):
    """Kink hook: the piece of the law at the end of the step (9·band piece + 3·target piece + poppet piece): the
    hysteresis band's piece of :func:`play_output` (0 without hysteresis), the first-order target's clip below,
    inside, above [0, 1] (0, 1, 2; always 1 for the second order) and the poppet on its seat, moving, at its stop
    (0, 1, 2)."""
    dp = p_in - p_out
    z, play = play_output(row, state[MEMORY], dp)
    clipped = 1 if row[ORDER] != 1.0 or 0.0 < z < 1.0 else (0 if z <= 0.0 else 2)
    y = advance(row, state, h, dp)[0]
    return 9 * play + 3 * clipped + (0 if y <= 0.0 else (2 if y >= 1.0 else 1))


@kernel
def flow_with_derivatives(row, state, h, p_in, p_out, p_pilot):
    """Flow Q [m³/s] from inlet to outlet at the end of a step of ``h`` [s] that starts at the poppet states
    ``state`` and ends at the absolute port pressures [Pa], and dQ/dp_in, dQ/dp_out, dQ/dp_pilot (= 0)
    [m³/(s·Pa)]."""
    dp = p_in - p_out
    y, rate, slope = advance(row, state, h, dp)
    area = row[LEAKAGE] + row[AREA] * y
    q, g = orifice_flow_with_derivative(area, row[K], row[C], dp)
    total = g + orifice_flow_area_derivative(area, row[K], row[C], dp) * row[AREA] * slope
    return q, total, -total, 0.0


@kernel
def step_end(row, state, h, p_in, p_out, p_pilot, out):
    """The poppet states at the end of the step of :func:`flow_with_derivatives` into ``out`` (may be ``state``)."""
    dp = p_in - p_out
    y, rate, slope = advance(row, state, h, dp)
    memory = play_output(row, state[MEMORY], dp)[0] if row[PLAY] > 0.0 else 0.0
    out[Y], out[RATE], out[MEMORY] = y, rate, memory


@dataclass(frozen=True, kw_only=True)
class ReliefPoppet:
    """Relief valve with poppet dynamics (ports inlet, outlet; states opening, opening_rate); law
    :func:`flow_with_derivatives`."""

    cracking_pressure: float = param("Pa", low=0.0, high=1e9)
    """Differential pressure at which the poppet lifts off its seat [Pa]."""
    full_open_pressure: float = param("Pa", low=0.0, high=1e9)
    """Differential pressure that holds the poppet fully open in steady state [Pa] (> cracking)."""
    area: float = param("m^2", low=0.0, high=0.01)
    """Flow area fully open [m²]."""
    leakage_area: float = param("m^2", low=0.0, high=1e-5, low_open=False, default=1e-11)
    """Flow area closed [m²]."""
    discharge_coefficient: float = param("-", low=0.0, high=1.0, default=0.7)
    """C_d [-]."""
    dynamics: str = param("-", default="second_order", choices=("first_order", "second_order"))
    """Poppet model: first-order lag or mass–spring–damper."""
    time_constant: float = param("s", low=0.0, high=10.0, low_open=False, default=0.002)
    """First order: τ [s] (0: no lag)."""
    natural_frequency: float = param("rad/s", low=0.0, high=1e6, default=600.0)
    """Second order: ω = √(k/m) [rad/s]."""
    damping_ratio: float = param("-", low=0.0, high=100.0, low_open=False, default=0.5)
    """Second order: ζ [-]."""
    reseat_pressure: float = param("Pa", low=0.0, high=1e9, low_open=False, default=None)
    """Differential pressure below which an opened poppet closes again [Pa] (≤ cracking; the hysteresis band is
    p_crack − p_reseat); default: the cracking pressure, no hysteresis."""
    PORTS = ("inlet", "outlet")
    LAW_COLUMNS = COLUMNS
    STATES = STATES
    STATE_UNITS = ("-", "1/s", "-")
    BRANCH_LAW = flow_with_derivatives
    STATE_END = step_end
    LAW_PIECE = law_piece

    def check(self, where: str) -> None:
        if self.reseat_pressure is not None and self.reseat_pressure > self.cracking_pressure:
            raise CircuitError(f"{where}, field 'reseat_pressure': {self.reseat_pressure!r} is above cracking_pressure "
                               f"({self.cracking_pressure!r} Pa); allowed: [0, cracking_pressure] Pa")
        if not self.full_open_pressure > self.cracking_pressure:
            raise CircuitError(f"{where}, field 'full_open_pressure': {self.full_open_pressure!r} is not above "
                               f"cracking_pressure ({self.cracking_pressure!r} Pa)")

    def state_start(self) -> tuple:
        """The poppet at rest on its seat, the play at zero: (opening, opening_rate, play) = (0, 0, 0)."""
        return (0.0, 0.0, 0.0)

    def law_row(self, fluid) -> np.ndarray:
        """This valve's row of :data:`COLUMNS` in ``fluid`` (a :class:`~hydraulics.fluid.Fluid`)."""
        k, c = orifice_coefficients(self.discharge_coefficient, fluid.density, fluid.kinematic_viscosity)
        return table(COLUMNS, 1, cracking=self.cracking_pressure, span=self.full_open_pressure - self.cracking_pressure,
                     area=self.area, leakage=self.leakage_area, k=k, c=c,
                     order=1.0 if self.dynamics == "first_order" else 2.0, tau=self.time_constant,
                     omega=self.natural_frequency, zeta=self.damping_ratio, play=self.play())[0]

    def play(self) -> float:
        """Hysteresis band w = (p_crack − p_reseat)/(p_full − p_crack) [-] (0 without hysteresis)."""
        if self.reseat_pressure is None:
            return 0.0
        return (self.cracking_pressure - self.reseat_pressure) / (self.full_open_pressure - self.cracking_pressure)
