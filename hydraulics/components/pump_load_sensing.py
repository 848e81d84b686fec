"""Load-sensing variable pump: the swash plate moves until the pump's outlet stands a margin above the highest load
pressure (the LS line), within a pressure cut-off.

The regulator compares the outlet pressure with the LS pressure plus the margin (the LS spool's spring) and, above
the cut-off, with the cut-off setting; its spool drives the swash actuator, so the displacement fraction α ∈ [0, 1]
integrates the error at a rate limited by the actuator:

    e = min(p_LS + Δp_LS − p_out,  p_cut − (p_out − p_in)),      τ·α̇ = clip(e/w, −1, 1),

with the band w over which the regulator opens fully and τ the swash plate's full-stroke time.  Flow
Q = η_v·D·n·α from ``inlet`` to ``outlet`` at the shaft speed n.  In steady state with 0 < α < 1, e = 0: the
outlet holds p_LS + Δp_LS (Δp_LS the *margin*) while the LS line is below the cut-off; with the LS line vented to
tank it stands by at the margin above the tank (the standby pressure).

**Step.**  Over a step of h, backward Euler on α with the end pressures, α⁺ = clip(α + (h/τ)·clip(e⁺/w, −1, 1), 0, 1),
affine in the pressures inside the band: the network's Newton solve sees the flow at the end of the step with

    ∂Q/∂p_out = −η_v·D·n·h/(τ·w),   ∂Q/∂p_LS = +η_v·D·n·h/(τ·w)   (LS term active; the cut-off term: ∂/∂p_out only,
    ∂Q/∂p_in = −∂Q/∂p_out),

and zero where the regulator or the swash plate saturates (the kink hook :func:`law_piece` numbers those pieces).

State: ``displacement_fraction`` α [-], 0 at rest.  Ports: ``inlet``, ``outlet``, ``ls`` (the LS line, read
only).  The pump's work Q·(μ_out − μ_in) enters the energy ledger as pump work (:attr:`SOURCE`).

Limitations: the shaft speed is a parameter (not a scheduled input); no torque limiter; no regulator spool
dynamics of its own (its lag is the swash actuator's τ); leakage not modelled.

References: H. Exner et al., *Hydraulics: Basic Principles and Components*, Bosch Rexroth 2011 (load-sensing
variable pumps: margin, standby, pressure cut-off); Hopsan component library, *HydraulicPumpLoadSensing*.

Example
-------
>>> import numpy as np
>>> from hydraulics.fluid import Fluid
>>> pump = PumpLoadSensing(displacement=2e-5, speed=30.0, margin=2e6, cutoff_pressure=3e7)
>>> row, ambient, state = pump.law_row(Fluid()), Fluid().reference_pressure, np.array([0.5])
>>> step_end(row, state, 0.01, ambient, ambient + 1.1e7, ambient + 1e7, state)  # 10 bar short of the margin
>>> float(state[0]) > 0.5
True
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._jit import kernel
from .parameters import param, table

COLUMNS = ("rate", "margin", "cutoff", "band", "tau")
"""Row of one pump: η_v·D·n [m³/s at full displacement], margin Δp_LS [Pa], cut-off (gauge) [Pa], regulator band w
[Pa], full-stroke time τ [s]."""
RATE, MARGIN, CUTOFF, BAND, TAU = range(len(COLUMNS))


@kernel
def swash_step(row, alpha, h, p_in, p_out, p_ls):
    """α⁺ [-] after ``h`` [s] with the end pressures [Pa], and ∂α⁺/∂p_in, ∂α⁺/∂p_out, ∂α⁺/∂p_LS [1/Pa]."""
    band = row[BAND]
    ls_error = p_ls + row[MARGIN] - p_out
    cut_error = row[CUTOFF] - (p_out - p_in)
    gain = h / (row[TAU] * band)
    if ls_error <= cut_error:
        error, d_in, d_out, d_ls = ls_error, 0.0, -gain, gain
    else:
        error, d_in, d_out, d_ls = cut_error, gain, -gain, 0.0
    if error >= band or error <= -band:  # the regulator saturated: the swash plate moves at full rate
        error = band if error > 0.0 else -band
        d_in = d_out = d_ls = 0.0
    alpha_end = alpha + gain * error
    if alpha_end <= 0.0:
        return 0.0, 0.0, 0.0, 0.0
    if alpha_end >= 1.0:
        return 1.0, 0.0, 0.0, 0.0
    return alpha_end, d_in, d_out, d_ls


@kernel
def law_piece(row, state, h, p_in, p_out, p_ls):
    """Kink hook: 9·(cut-off active) + 3·(regulator below, inside, above its band) + (swash plate at zero, between,
    at full) at the end of the step."""
    band = row[BAND]
    ls_error = p_ls + row[MARGIN] - p_out
    cut_error = row[CUTOFF] - (p_out - p_in)
    error = ls_error if ls_error <= cut_error else cut_error
    regulator = 0 if error <= -band else (2 if error >= band else 1)
    alpha = swash_step(row, state[0], h, p_in, p_out, p_ls)[0]
    return (9 if ls_error > cut_error else 0) + 3 * regulator + (0 if alpha <= 0.0 else (2 if alpha >= 1.0 else 1))


@kernel
def flow_with_derivatives(row, state, h, p_in, p_out, p_ls):
    """Flow Q [m³/s] from inlet to outlet at the end of a step of ``h`` [s] from the displacement fraction ``state[0]``
    and ∂Q/∂p_in, ∂Q/∂p_out, ∂Q/∂p_LS [m³/(s·Pa)] at the end pressures [Pa]."""
    alpha, d_in, d_out, d_ls = swash_step(row, state[0], h, p_in, p_out, p_ls)
    rate = row[RATE]
    return rate * alpha, rate * d_in, rate * d_out, rate * d_ls


@kernel
def step_end(row, state, h, p_in, p_out, p_ls, out):
    """The displacement fraction at the end of the step of :func:`flow_with_derivatives` into ``out``."""
    out[0] = swash_step(row, state[0], h, p_in, p_out, p_ls)[0]


@dataclass(frozen=True, kw_only=True)
class PumpLoadSensing:
    """Load-sensing variable pump with pressure cut-off (ports inlet, outlet, ls; state displacement_fraction)."""

    displacement: float = param("m^3/rev", low=0.0, high=0.05)
    """Displacement at full swash D [m³/rev]."""
    speed: float = param("rev/s", low=0.0, high=1000.0)
    """Shaft speed n [rev/s] (held)."""
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
    PORTS = ("inlet", "outlet", "ls")
    LAW_COLUMNS = COLUMNS
    STATES = ("displacement_fraction",)
    STATE_UNITS = ("-",)
    BRANCH_LAW = flow_with_derivatives
    STATE_END = step_end
    LAW_PIECE = law_piece
    SOURCE = True
    """Its flow's power Q·(μ_out − μ_in) is pump work, not dissipation."""

    def state_start(self) -> tuple:
        """At rest: swash plate at zero."""
        return (0.0,)

    def law_row(self, fluid) -> np.ndarray:
        """This pump's row of :data:`COLUMNS` (``fluid`` unused: the law is volumetric)."""
        return table(COLUMNS, 1, rate=self.volumetric_efficiency * self.displacement * self.speed, margin=self.margin,
                     cutoff=self.cutoff_pressure, band=self.regulator_band, tau=self.stroke_time)[0]
