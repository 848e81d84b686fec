"""Load-sensing variable pump: the swash plate moves until the pump's outlet stands a margin above the highest load
pressure (the LS line), within a pressure cut-off.

The regulator compares the outlet pressure with the LS pressure plus the margin (the LS spool's spring) and, above
the cut-off, with the cut-off setting; its spool drives the swash actuator.  The displacement fraction α ∈ [0, 1]
is a PI law of that error: an integral part I that the swash actuator moves at a rate limited by its full-stroke
time, plus an optional proportional part (the regulator spool's direct action on the swash plate):

    e = min(p_LS + Δp_LS − p_out,  p_cut − (p_out − p_in)),      τ·İ = clip(e/w, −1, 1),  I ∈ [0, 1],
    α = clip(I + k_p·e, 0, 1),

with the band w over which the regulator opens fully, τ the swash plate's full-stroke time and k_p [1/Pa] the
proportional gain (0: a pure integrator, α = I).  Flow from ``inlet`` to ``outlet`` at the shaft speed n (the
component's scheduled input ``speed`` [rev/s], by default its field ``speed``), less a laminar leakage (case drain
and slippage, returned to the inlet side) of coefficient C_L:

    Q = η_v·D·n·α − C_L·(p_out − p_in).

In steady state with 0 < α < 1, e = 0: the outlet holds p_LS + Δp_LS (Δp_LS the *margin*) while the LS line is
below the cut-off; with the LS line vented to tank it stands by at the margin above the tank (the standby
pressure), the swash plate just covering the leakage.

Why the two extra terms: with every section closed the supply volume V and the pure integrator form an undamped
loop (pressure integrates the flow, the flow integrates the error) of angular frequency ω = √(β·η_v·D·n/(V·τ·w)),
and without leakage nothing lowers a supply that stands above the standby pressure.  The proportional part adds the
damping ζ = β·η_v·D·n·k_p/(2·V·ω); the leakage lets the supply fall to standby with the time constant V/(β·C_L).

**Step.**  Over a step of h, backward Euler on I with the end pressures, I⁺ = clip(I + (h/τ)·clip(e⁺/w, −1, 1), 0, 1),
α⁺ = clip(I⁺ + k_p·e⁺, 0, 1), affine in the pressures inside the band and off the clips: the network's Newton
solve sees the flow at the end of the step with

    ∂Q/∂p_out = −η_v·D·n·g − C_L,   ∂Q/∂p_LS = +η_v·D·n·g,   g = ∂I⁺/∂e + k_p = h/(τ·w) + k_p
    (LS term active; the cut-off term: ∂e/∂p_out = −1, ∂e/∂p_in = +1),

each part zero where the regulator, the integral or the swash plate saturates (the kink hook :func:`law_piece`
numbers those pieces).

States: ``displacement_fraction`` α [-] (the swash plate) and ``regulator_integral`` I [-], both 0 at rest.
Ports: ``inlet``, ``outlet``, ``ls`` (the LS line, read only).  The pump's net work Q·(μ_out − μ_in) enters the
energy ledger as pump work (:attr:`SOURCE`); the leakage's loss is therefore inside the pump.

Limitations: no torque limiter; the regulator spool has no dynamics of its own (its lag is the swash actuator's τ).
The regulator does not see the shaft speed (it compares pressures): a change of speed changes the flow at once,
the displacement only through the pressures it moves.

References: H. Exner et al., *Hydraulics: Basic Principles and Components*, Bosch Rexroth 2011 (load-sensing
variable pumps: margin, standby, pressure cut-off); Hopsan component library, *HydraulicPumpLoadSensing*.

Example
-------
>>> import numpy as np
>>> from hydraulics.fluid import Fluid
>>> pump = PumpLoadSensing(displacement=2e-5, speed=30.0, margin=2e6, cutoff_pressure=3e7)
>>> row, ambient, state = pump.law_row(Fluid()), Fluid().reference_pressure, np.array([0.5, 0.5])
>>> step_end(row, state, 0.01, ambient, ambient + 1.1e7, ambient + 1e7, state)  # 10 bar short of the margin
>>> float(state[0]) > 0.5
True
>>> speed = np.array(pump.input_start())  # [rev/s]: what a scenario schedules by the component's name
>>> q = flow_with_derivatives(row, state, 0.0, ambient, ambient + 1.1e7, ambient + 1e7, speed)[0]
>>> round(q / (2e-5 * 30.0 * float(state[0])), 12)  # Q = η_v·D·n·α
1.0
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._jit import kernel
from .parameters import param, table

COLUMNS = ("rate", "margin", "cutoff", "band", "tau", "gain", "leak")
"""Row of one pump: η_v·D [m³/rev at full displacement], margin Δp_LS [Pa], cut-off (gauge) [Pa], regulator band w
[Pa], full-stroke time τ [s], proportional gain k_p [1/Pa], leakage coefficient C_L [m³/(s·Pa)]."""
RATE, MARGIN, CUTOFF, BAND, TAU, GAIN, LEAK = range(len(COLUMNS))


@kernel
def swash_step(row, state, h, p_in, p_out, p_ls):
    """α⁺ and I⁺ [-] after ``h`` [s] from ``state`` = (α, I) with the end pressures [Pa], and ∂α⁺/∂p_in,
    ∂α⁺/∂p_out, ∂α⁺/∂p_LS [1/Pa]."""
    band = row[BAND]
    ls_error = p_ls + row[MARGIN] - p_out
    cut_error = row[CUTOFF] - (p_out - p_in)
    gain = h / (row[TAU] * band)
    if ls_error <= cut_error:
        error, e_in, e_out, e_ls = ls_error, 0.0, -1.0, 1.0
    else:
        error, e_in, e_out, e_ls = cut_error, 1.0, -1.0, 0.0
    proportional = row[GAIN] * error
    if error >= band or error <= -band:  # the regulator saturated: the swash actuator moves at full rate
        error = band if error > 0.0 else -band
        gain_now = 0.0
    else:
        gain_now = gain
    integral = state[1] + gain * error
    if integral <= 0.0:
        integral, gain_now = 0.0, 0.0
    elif integral >= 1.0:
        integral, gain_now = 1.0, 0.0
    alpha = integral + proportional
    slope = gain_now + row[GAIN]
    if alpha <= 0.0:
        return 0.0, integral, 0.0, 0.0, 0.0
    if alpha >= 1.0:
        return 1.0, integral, 0.0, 0.0, 0.0
    return alpha, integral, slope * e_in, slope * e_out, slope * e_ls


@kernel
def law_piece(row, state, h, p_in, p_out, p_ls):
    """Kink hook: 27·(integral at zero, between, at full) + 9·(cut-off active) + 3·(regulator below, inside, above
    its band) + (swash plate at zero, between, at full) at the end of the step."""
    band = row[BAND]
    ls_error = p_ls + row[MARGIN] - p_out
    cut_error = row[CUTOFF] - (p_out - p_in)
    error = ls_error if ls_error <= cut_error else cut_error
    regulator = 0 if error <= -band else (2 if error >= band else 1)
    alpha, integral = swash_step(row, state, h, p_in, p_out, p_ls)[:2]
    ends = 27 * (0 if integral <= 0.0 else (2 if integral >= 1.0 else 1))
    return ends + (9 if ls_error > cut_error else 0) + 3 * regulator + (0 if alpha <= 0.0 else (2 if alpha >= 1.0 else 1))


@kernel
def flow_with_derivatives(row, state, h, p_in, p_out, p_ls, inputs):
    """Flow Q [m³/s] from inlet to outlet at the end of a step of ``h`` [s] from the states ``state`` = (α, I) at
    the shaft speed ``inputs[0]`` [rev/s] and ∂Q/∂p_in, ∂Q/∂p_out, ∂Q/∂p_LS [m³/(s·Pa)] at the end pressures [Pa]."""
    alpha, _, d_in, d_out, d_ls = swash_step(row, state, h, p_in, p_out, p_ls)
    rate, leak = row[RATE] * inputs[0], row[LEAK]
    return rate * alpha - leak * (p_out - p_in), rate * d_in + leak, rate * d_out - leak, rate * d_ls


@kernel
def step_end(row, state, h, p_in, p_out, p_ls, out):
    """The states (α, I) at the end of the step of :func:`flow_with_derivatives` into ``out``."""
    alpha, integral = swash_step(row, state, h, p_in, p_out, p_ls)[:2]
    out[0] = alpha
    out[1] = integral


@dataclass(frozen=True, kw_only=True)
class PumpLoadSensing:
    """Load-sensing variable pump with pressure cut-off (ports inlet, outlet, ls; state displacement_fraction)."""

    displacement: float = param("m^3/rev", low=0.0, high=0.05)
    """Displacement at full swash D [m³/rev]."""
    speed: float = param("rev/s", low=0.0, high=1000.0)
    """Shaft speed n [rev/s] when no scenario schedules it (the input ``speed``)."""
    volumetric_efficiency: float = param("-", low=0.0, high=1.0, default=1.0)
    """η_v [-]."""
    margin: float = param("Pa", low=0.0, high=1e8, default=2e6)
    """LS margin Δp_LS: outlet pressure above the LS line [Pa] (also the standby pressure above tank)."""
    cutoff_pressure: float = param("Pa", low=0.0, high=1e9)
    """Pressure cut-off: outlet pressure above the inlet at which the pump destrokes [Pa]."""
    regulator_band: float = param("Pa", low=0.0, high=1e8, default=5e5)
    """Pressure error over which the regulator opens fully [Pa]."""
    stroke_time: float = param("s", low=0.0, high=10.0, default=0.05)
    """Swash plate's full-stroke time τ at the regulator fully open [s]."""
    proportional_gain: float = param("1/Pa", low=0.0, high=1e-3, default=0.0)
    """Proportional gain k_p of the regulator: displacement fraction per pascal of error [1/Pa] (0: integral only)."""
    leakage: float = param("m^3/(s*Pa)", low=0.0, high=1e-6, default=0.0)
    """Laminar leakage coefficient C_L from outlet to inlet [m³/(s·Pa)] (e.g. 5 % of 430 L/min at 250 bar:
    1.4e-11)."""
    PORTS = ("inlet", "outlet", "ls")
    LAW_COLUMNS = COLUMNS
    STATES = ("displacement_fraction", "regulator_integral")
    STATE_UNITS = ("-", "-")
    INPUTS = ("speed",)
    INPUT_UNITS = ("rev/s",)
    BRANCH_LAW = flow_with_derivatives
    STATE_END = step_end
    LAW_PIECE = law_piece
    SOURCE = True
    """Its flow's power Q·(μ_out − μ_in) is pump work, not dissipation."""

    def state_start(self) -> tuple:
        """At rest: swash plate and regulator integral at zero."""
        return (0.0, 0.0)

    def input_start(self) -> tuple:
        """The shaft speed [rev/s] when no scenario schedules it: the field ``speed``."""
        return (self.speed,)

    def law_row(self, fluid) -> np.ndarray:
        """This pump's row of :data:`COLUMNS` (``fluid`` unused: the law is volumetric)."""
        return table(COLUMNS, 1, rate=self.volumetric_efficiency * self.displacement, margin=self.margin,
                     cutoff=self.cutoff_pressure, band=self.regulator_band, tau=self.stroke_time,
                     gain=self.proportional_gain, leak=self.leakage)[0]
