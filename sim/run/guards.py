"""Load-time stability guards: the oil-column frequency of every actuator against the chosen step.

Each cylinder (and motor) sees its chambers as springs, k = Σ β_eff·A²/V over
its non-tank chambers (motors: A → D/2π), acting on the inertia the actuator
sees, m_eff = 1/(J·M⁻¹·Jᵀ) from MuJoCo's mass matrix at the initial pose, taken
through the MJCF's equality constraints (loop closures: the inertia of the
constrained system, :func:`inertia_seen`).  Merritt's hydraulic
frequency is then ω_h = √(k/m_eff), see
:func:`hydraulics.components.cylinder.hydraulic_natural_frequency`, and the two numbers that
decide whether a step size is stable are ω_h·dt and k·dt²/m_eff = (ω_h·dt)².

What is known about the schemes (``docs/stability/`` has the measured maps):

``implicit`` (MuJoCo, linearly implicit coupling) and ``pbd`` (compliant constraint)
    Stable for any ω_h·dt; an unresolved column (ω_h·dt > √2) is damped
    numerically (θ > 0), which costs accuracy, not stability.
``explicit`` and ``pbd-naive``
    Forward-Euler co-simulation: per step the oil-column mode is multiplied by
    |1 + h·λ|, and |1 + h·λ|² = 1 − 2ζ·ω_h·h + (ω_h·h)², so the scheme is
    unstable for any dt without physical damping (ζ = 0) and otherwise needs
    ω_h·dt < 2ζ.  Seal friction, valve flow gains and joint damping make the
    practical limit ω_h·dt ≈ 0.1–0.2 on real machines (``EXPLICIT_OMEGA_DT_LIMIT``).

Rigid actuators (``incompressible`` among compressible ones, :class:`hydraulics.coupling.CouplingMixed`)
have no chambers of their own; their column is the supply net they draw from,
k = β_eff·A_cap²/V_P (motors: D/2π).  Measured on the excavator dig (stick, bucket
and swing rigid; ω·dt of the bucket, the stiffest): MuJoCo mode loses energy as it
should (residual +5.9 % of the pump work over the first 3.5 s) at 1 and 2 ms
(ω·dt ≤ 0.36); at 5 ms (0.9) it completes the 20 s dig but creates 3 % of the pump
work during the soil contact; at 10 ms (1.8) it diverges at 14.6 s and at 1/30 s (6)
at 2.8 s: the supply's pressure kinks (cavitation floor, relief) break the
linearisation when its column is not resolved.  The guards warn above
``RIGID_SUPPLY_OMEGA_DT`` (PBD mode: per XPBD substep).

With coupling ``explicit`` the network itself is stepped by forward Euler
(``explicit_euler``), whose own limit is h < 2·V/(β_eff·G) for a node of volume V
behind a branch of slope G; the guards check it for every relief valve (a fixed
G = its gradient, the branch a dead-headed pump ends on) and report it in
``node_limits``.

:func:`check_plant` (or :func:`check_scenario`) returns a :class:`GuardReport`
whose ``rows`` hold these numbers per actuator and whose ``warnings`` say which
setting would be stable.  Guards never fail a run for stability; a state that is
not finite at t = 0 is bad input (:func:`check_initial_state`).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field

import mujoco
import numpy as np

from hydraulics.components import cylinder as _cylinder
from hydraulics.network import ACTUATOR_CYLINDER

from sim.plants.constraints import (HOLDING_RESIDUAL_WARN, actuator_moments, closure_gaps, inverse_inertia,
                                    start_contacts)

# The cylinder's laws as Python functions (``py_func`` of the compiled law; the law itself under NUMBA_DISABLE_JIT): the
# guards call them a few times per run from Python, where compiling them (every process: a law is not cached on its
# own, see hydraulics._jit) would cost about a second of every run's start-up.
hydraulic_stiffness = getattr(_cylinder.hydraulic_stiffness, "py_func", _cylinder.hydraulic_stiffness)
hydraulic_natural_frequency = getattr(_cylinder.hydraulic_natural_frequency, "py_func",
                                      _cylinder.hydraulic_natural_frequency)

# Practical explicit limit on ω_h·dt with typical physical damping (seal friction, valve
# flow gain); measured on the boom and excavator maps (docs/stability/), 0.1–0.2 in the literature.
EXPLICIT_OMEGA_DT_LIMIT = 0.1  # [-]
# Below this damping ratio an oil column counts as undamped: explicit diverges at any dt.
UNDAMPED_RATIO = 1e-3  # [-]
# ω_h·dt beyond which the implicit coupling damps the oil column numerically (θ > 0, see
# hydraulics.coupling.blend_factor): stable, but the ω_h oscillation is not resolved.
IMPLICIT_RESOLVED_OMEGA_DT = math.sqrt(2.0)  # [-]
# ω·h up to which a rigid actuator's supply column was measured stable (see module docstring).
RIGID_SUPPLY_OMEGA_DT = 0.5  # [-]
# ω_local·dt above which a cylinder's own rod body, held by MuJoCo's soft loop-closure equality, rings unstably
# (tests/scenes/loop_arm.xml with a 10 kg rod: ω_local·dt = 1.52 holds, 1.77 and 2.53 diverge; the θ-rule's √2).
LOCAL_MODE_OMEGA_DT = math.sqrt(2.0)  # [-]
CLOSURE_GAP_WARN = 1e-3
"""Largest static opening [m] of a ``connect`` closure at the start pose before a warning (MuJoCo mode): a closure that
opens more lets the machine sag with every pressure still plausible (:func:`sim.plants.constraints.closure_gaps`)."""
STIFF_SOLREF_STEPS = 2.0
"""``solref`` time constant suggested for a stretching closure, in steps: MuJoCo's documented lower bound, 2·dt."""
STIFF_SOLIMP = (0.99, 0.999, 0.001, 0.5, 2.0)
"""``solimp`` suggested for a stretching closure (the settings of hydroplant's own loop-closure scenes)."""
# The pins' own bodies count as a separate local mode when their inertia is below this fraction of the constrained one.
LOCAL_MASS_RATIO = 0.5  # [-]
# Methods (mode or coupling names) that step the oil column with forward Euler.
EXPLICIT_METHODS = ("explicit", "pbd-naive")


@dataclass(frozen=True)
class GuardRow:
    """Stability numbers of one actuator at the initial state."""

    actuator: str
    """Circuit name of the cylinder or motor."""
    kind: str
    """``"cylinder"`` or ``"motor"``."""
    effective_mass: float
    """Inertia the actuator sees, 1/(J·M⁻¹·Jᵀ) [kg or kg·m²]."""
    stiffness: float
    """Oil-column stiffness Σ β_eff·A²/V over its non-tank chambers [N/m or N·m/rad]."""
    damping: float
    """Physical linear damping the actuator sees: viscous seal friction + joint damping [N·s/m or N·m·s/rad]."""
    omega_h: float
    """Hydraulic natural frequency √(k/m_eff) [rad/s]."""
    omega_h_dt: float
    """ω_h·dt [-]."""
    k_dt2_over_m: float
    """k·dt²/m_eff = (ω_h·dt)² [-]."""
    damping_ratio: float
    """ζ = c/(2·√(k·m_eff)) [-] from ``damping``."""
    explicit_max_dt: float
    """Largest dt [s] at which forward-Euler co-simulation is expected stable: max(2ζ, practical limit)/ω_h
    (× ``pbd_substeps`` in the PBD modes), 0 if undamped."""
    stable: bool
    """Whether the chosen method is expected to be stable for this actuator at the chosen dt."""
    rigid: bool = False
    """A rigid (``incompressible`` among compressible) actuator: its column is its supply net, and
    ``explicit_max_dt`` holds the step that resolves it for the mixed coupling, RIGID_SUPPLY_OMEGA_DT/ω (× substeps)."""

    @property
    def frequency_hz(self) -> float:
        """ω_h/2π [Hz]."""
        return self.omega_h / (2.0 * math.pi)


@dataclass(frozen=True)
class GuardReport:
    """Guard verdict for one plant: per-actuator rows, warnings (may be empty) and notes."""

    mode: str
    coupling: str
    dt: float
    rows: tuple = ()
    warnings: tuple = ()
    notes: tuple = field(default=())
    node_limits: tuple = ()
    """(relief name, node name, V [m³], β_eff [Pa], G [m³/(s·Pa)], explicit-Euler dt limit 2V/(β_eff·G) [s]) per relief valve."""

    @property
    def method(self) -> str:
        """``"explicit"``, ``"implicit"``, ``"pbd"`` or ``"pbd-naive"``: the scheme that steps the oil column."""
        return method_name(self.mode, self.coupling)

    @property
    def max_omega_h_dt(self) -> float:
        return max((r.omega_h_dt for r in self.rows), default=0.0)

    def table(self) -> str:
        """Human-readable table of the rows."""
        head = f"{'actuator':<16s} {'m_eff':>10s} {'k':>10s} {'f_h [Hz]':>9s} {'w_h*dt':>8s} {'k*dt^2/m':>9s} {'zeta':>7s} {'explicit dt_max [s]':>20s}"
        lines = [f"guards: mode {self.mode}, coupling {self.coupling}, dt {self.dt:g} s", head]
        for r in self.rows:
            lines.append(
                f"{r.actuator:<16s} {r.effective_mass:10.4g} {r.stiffness:10.4g} {r.frequency_hz:9.4g} {r.omega_h_dt:8.3g} "
                f"{r.k_dt2_over_m:9.3g} {r.damping_ratio:7.2g} {r.explicit_max_dt:20.3g}"
            )
        for relief, node, volume, beta, gradient, limit in self.node_limits:
            lines.append(f"relief {relief} on node {node}: V {volume:.4g} m^3, beta_eff {beta:.4g} Pa, G {gradient:.4g} m^3/(s*Pa): "
                         f"explicit stepper needs dt < {limit:.3g} s")
        lines += [f"warning: {w}" for w in self.warnings] + [f"note: {n}" for n in self.notes]
        return "\n".join(lines)


def method_name(mode: str, coupling: str) -> str:
    """The scheme that steps the oil column: the coupling in MuJoCo mode, the PBD variant otherwise."""
    return coupling if mode == "mujoco" else mode


def expected_stable(method: str, row_omega_h_dt: float, damping_ratio: float) -> bool:
    """Whether ``method`` is expected stable at this ω_h·dt and damping ratio (see module docstring)."""
    if method not in EXPLICIT_METHODS:
        return True
    if damping_ratio < UNDAMPED_RATIO:
        return row_omega_h_dt == 0.0
    return row_omega_h_dt <= max(2.0 * damping_ratio, EXPLICIT_OMEGA_DT_LIMIT)


# ----------------------------------------------------------------------------- numbers
def inertia_seen(mjmodel, qpos, actuator_id, *, constrained: bool = True):
    """Effective inertia and joint damping seen by each actuator at ``qpos``, through the constrained system.

    Returns ``(effective_mass, joint_damping)``, each shape (actuator_count,).
    The effective mass is 1/(j·N·(Nᵀ·M·N)⁻¹·Nᵀ·jᵀ) with N the null space of the
    MJCF's equality constraints (:func:`hydraulics.equilibrium.constrained_inverse_inertia`):
    a cylinder whose pins sit on its own barrel and rod bodies, closed onto the
    links by ``connect`` equalities, sees the links' inertia, as with pins on the links.
    The joint damping is m_eff²·Σ_j d_j·u_j², u the velocity field a unit actuator
    impulse induces.  ``constrained=False``: the equalities ignored (the pins' own bodies only).
    """
    inverse, velocity = inverse_inertia(mjmodel, qpos, lambda d: actuator_moments(mjmodel, d, actuator_id), constrained=constrained)
    with np.errstate(divide="ignore"):
        mass = np.where(inverse > 0, 1.0 / np.where(inverse > 0, inverse, 1.0), np.inf)
    damping = np.where(np.isfinite(mass), mass**2 * (velocity.T**2 @ mjmodel.dof_damping), 0.0)
    return mass, damping


def oil_column_stiffness(network, pressure, position) -> np.ndarray:
    """Σ A²/C over each actuator's non-tank chambers [N/m or N·m/rad], shape (actuator_count,), with C the compliance
    [m³/Pa] of the chamber's oil: V/β_eff of its node plus that of every node a hose built as a π-line joins to it
    (``lines`` fidelity).  The line's laminar resistance is neglected: at the oil column's frequency ω its end
    volumes are one compliance while ω·C_line/G_line ≪ 1 (a 3 m, 16 mm hose: 4e-3 at 20 Hz), which is the column
    a closed valve traps; a long thin line at a high frequency is stiffer than this says."""
    beta = network.effective_bulk_modulus(pressure, position)
    volume, _ = network.node_volume_at(position, pressure)
    free = ~network.node_fixed
    group = np.arange(network.node_count)  # the node that stands for each node's line-joined group

    def root(n):
        while group[n] != n:
            group[n] = group[group[n]]
            n = group[n]
        return n

    lines = {f"{hose}.line" for hose in network.hose_lines}
    for b, name in enumerate(network.branch_names):
        if name in lines and free[network.branch_from[b]] and free[network.branch_to[b]]:
            group[root(network.branch_from[b])] = root(network.branch_to[b])
    oil, compliance = np.zeros(network.node_count), np.zeros(network.node_count)
    for n in np.flatnonzero(free):
        oil[root(n)] += float(volume[n])
        compliance[root(n)] += float(volume[n]) / float(beta[n])
    k = np.zeros(network.actuator_count)

    def add(a, node, area):
        if free[node]:
            g = root(node)
            k[a] += hydraulic_stiffness(oil[g] / compliance[g], area, oil[g])  # the group's β_eff = V/C

    for i, a in enumerate(network.cylinder_actuator):
        add(a, network.cylinder_cap_node[i], network.cylinder_cap_area[i])
        add(a, network.cylinder_rod_node[i], network.cylinder_rod_area[i])
    for i, a in enumerate(network.motor_actuator):
        rate = network.motor_displacement[i] / (2.0 * math.pi)
        add(a, network.motor_a_node[i], rate)
        add(a, network.motor_b_node[i], rate)
    # rigid actuators: the supply net of their rigid branch, on the larger (cap) area
    s = network.branch_slices.get("rigid", slice(0, 0))
    for b, a in zip(range(s.start, s.stop), network.rigid_branch_actuator):
        node = network.branch_from[b]
        if free[node]:
            k[a] = hydraulic_stiffness(beta[node], network.rigid_extend_area[b - s.start], volume[node])
    return k


# ------------------------------------------------------------------------------ checks
def check(scene, net_state, *, qpos=None, mode=None, coupling=None, dt=None, fidelity=None) -> GuardReport:
    """Guard report for ``scene`` with the network at ``net_state`` (see module docstring).

    Parameters
    ----------
    scene : sim.io.scene.Scene
        The loaded scene (its MjModel gives the inertia).
    net_state : hydraulics.network.NetworkState
        Network state whose pressures and positions set the chamber stiffness.
    qpos : ndarray, shape (nq,), optional
        Pose for the inertia; default: the scenario's initial pose.
    mode, coupling, dt, fidelity : optional
        Override the scenario's run settings.
    """
    from sim.io.scene import initial_qpos_qvel

    scenario = scene.scenario
    mode = mode or scenario.mode
    coupling = coupling or scenario.coupling
    dt = float(dt or scenario.dt)
    fidelity = fidelity or scenario.fidelity
    network = scene.network
    if fidelity == "incompressible":
        return GuardReport(mode, coupling, dt, notes=("incompressible fidelity: no oil-column states; the velocity-tracking coupling is stable at any dt",))
    if qpos is None:
        qpos, _ = initial_qpos_qvel(scene)
    mass, joint_damping = inertia_seen(scene.mjmodel, qpos, scene.binding.actuator_id)
    k = oil_column_stiffness(network, net_state.node_pressure, net_state.actuator_position)
    viscous = np.zeros(network.actuator_count)
    viscous[network.cylinder_actuator] = network.cylinder_viscous
    damping = viscous + joint_damping
    method = method_name(mode, coupling)
    # the PBD plant steps the oil column once per XPBD substep
    substeps = scenario.pbd_substeps if mode in ("pbd", "pbd-naive") else 1
    step = dt / substeps
    rows, warnings, notes = [], list(getattr(scene, "warnings", ())), list(getattr(scene, "notes", ()))
    for a, name in enumerate(network.actuator_names):
        m, ka, c = float(mass[a]), float(k[a]), float(damping[a])
        rigid = bool(network.actuator_rigid[a])
        if rigid and ka == 0.0:
            notes.append(f"{name}: fidelity incompressible without a valve: locked by a velocity tracker, no oil column")
            continue
        omega = hydraulic_natural_frequency(ka, m) if (ka > 0 and math.isfinite(m) and m > 0) else 0.0
        zeta = c / (2.0 * math.sqrt(ka * m)) if omega > 0 else math.inf
        limit = max(2.0 * zeta, EXPLICIT_OMEGA_DT_LIMIT) if zeta >= UNDAMPED_RATIO else 0.0
        row = GuardRow(
            actuator=name,
            kind="cylinder" if network.actuator_kind[a] == ACTUATOR_CYLINDER else "motor",
            effective_mass=m,
            stiffness=ka,
            damping=c,
            omega_h=omega,
            omega_h_dt=omega * dt,
            k_dt2_over_m=(omega * dt) ** 2,
            damping_ratio=zeta,
            explicit_max_dt=substeps * (RIGID_SUPPLY_OMEGA_DT if rigid else limit) / omega if omega > 0 else math.inf,
            rigid=rigid,
            stable=(omega * step <= RIGID_SUPPLY_OMEGA_DT) if rigid else expected_stable(method, omega * step, zeta),
        )
        rows.append(row)
        where = (
            f"{name}: omega_h = {omega:.4g} rad/s ({row.frequency_hz:.3g} Hz; m_eff {m:.4g}, k {ka:.4g}, zeta {zeta:.2g}), "
            f"omega_h*dt = {row.omega_h_dt:.3g}, k*dt^2/m = {row.k_dt2_over_m:.3g} at dt = {dt:g} s"
            + (f" (oil column stepped per XPBD substep: omega_h*h = {omega * step:.3g}, h = dt/{substeps})" if substeps > 1 else "")
        )
        if rigid:
            where = where.replace(f"{name}: ", f"{name} (incompressible, drawing from its supply net): ", 1)
            if not row.stable:
                warnings.append(
                    f"{where}: the rigid actuator's supply column is not resolved (omega*h > {RIGID_SUPPLY_OMEGA_DT:g}); the mixed "
                    f"coupling may create energy or diverge there; use dt <= {row.explicit_max_dt:.3g} s"
                    + (" (or more XPBD substeps)" if substeps > 1 else " (or mode pbd with substeps)")
                    + ", or give it the fidelity 'compressible'"
                )
        elif not row.stable:
            what = "explicit coupling" if method == "explicit" else "mode pbd-naive"
            if zeta < UNDAMPED_RATIO:
                growth = 0.5 * omega**2 * step
                warnings.append(
                    f"{where}: {what} steps this undamped oil column with forward Euler, which is unstable at any dt "
                    f"(amplitude grows about e-fold every {1.0 / growth:.3g} s); "
                    + ("use mode pbd (or mode mujoco with coupling implicit)" if method == "pbd-naive" else "use coupling implicit")
                )
            else:
                warnings.append(
                    f"{where}: {what} is expected to diverge for omega_h*dt > {limit:.3g} (forward Euler, 2*zeta = {2 * zeta:.2g}, "
                    f"practical limit {EXPLICIT_OMEGA_DT_LIMIT:g}); "
                    + ("use mode pbd" if method == "pbd-naive" else "use coupling implicit")
                    + f", or dt <= {row.explicit_max_dt:.3g} s"
                )
        elif method not in EXPLICIT_METHODS and row.omega_h_dt > IMPLICIT_RESOLVED_OMEGA_DT:
            notes.append(
                f"{where}: stable, but the oil-column oscillation is not resolved (numerically damped); "
                f"dt <= {0.2 / omega:.3g} s resolves it"
            )
    if mode == "mujoco" and scene.mjmodel.neq and rows:
        warnings += local_mode_warnings(scene, qpos, k, mass, dt, net_state.actuator_position)
        warnings += closure_gap_warnings(scene, qpos, dt)
    warnings += start_contact_warnings(scene, qpos, mode)
    limits = relief_limits(network, net_state)
    explicit_stepper = (mode == "pbd-naive") or (coupling == "explicit" and (scenario.stepper or "explicit_euler") == "explicit_euler")
    if explicit_stepper:
        for relief, node, volume, beta, gradient, limit in limits:
            if step >= limit:
                warnings.append(
                    f"relief '{relief}' on node '{node}' (V {volume:.3g} m^3, beta_eff {beta:.3g} Pa, gradient {gradient:.3g} m^3/(s*Pa)): "
                    f"the explicit Euler network stepper is unstable once it opens for a step >= 2/(G*sum(beta/V)) = {limit:.3g} s "
                    f"(step {step:g} s); " + ("use mode pbd" if mode == "pbd-naive" else "use coupling implicit")
                    + f", or dt < {limit * substeps:.3g} s"
                )
    return GuardReport(mode, coupling, dt, tuple(rows), tuple(warnings), tuple(notes), tuple(limits))


def local_mode_warnings(scene, qpos, stiffness, mass, dt, position) -> list:
    """Warnings for cylinders whose pins sit on light bodies held by MuJoCo's soft equalities (see ``LOCAL_MODE_OMEGA_DT``).

    With the barrel and rod modelled as bodies closed onto the links by ``connect``
    equalities, the oil column also acts on the rod body alone, held by the soft
    equality: a local mode of frequency ω_local = √(k/m_local), m_local the inertia
    the pins see with the equalities ignored.  MuJoCo mode keeps it stable while
    ω_local·dt ≤ ``LOCAL_MODE_OMEGA_DT``.  ``position``: the actuator extensions [m or rad] the
    stiffness was taken at (named in the warning).
    """
    local, _ = inertia_seen(scene.mjmodel, qpos, scene.binding.actuator_id, constrained=False)
    out = []
    for a, name in enumerate(scene.network.actuator_names):
        m_local, k = float(local[a]), float(stiffness[a])
        if not (k > 0 and 0 < m_local < LOCAL_MASS_RATIO * float(mass[a])):
            continue
        omega = hydraulic_natural_frequency(k, m_local)
        if omega * dt > LOCAL_MODE_OMEGA_DT:
            out.append(
                f"{name}: its pins sit on bodies of {m_local:.4g} kg closed onto the links by equality constraints; at extension "
                f"x = {float(position[a]):.4g} m the oil column rings them against MuJoCo's soft equality at {omega / (2 * math.pi):.4g} Hz, omega*dt = {omega * dt:.3g} "
                f"> {LOCAL_MODE_OMEGA_DT:.3g}, which diverges in MuJoCo mode; use dt <= {LOCAL_MODE_OMEGA_DT / omega:.3g} s, "
                "give the rod body its real mass, or put the tendon's sites on the links"
            )
    return out


def start_contact_warnings(scene, qpos, mode) -> list:
    """One warning naming every contact of the start pose with the load it carries at its penetration
    (:func:`sim.plants.constraints.start_contacts`), and whether the equilibrium start counted them
    (``[initial] start_contacts``; PBD mode's equilibrium never does)."""
    contacts = start_contacts(scene.mjmodel, qpos)
    if not contacts:
        return []
    counted = scene.scenario.start_contacts == "include" and mode == "mujoco"
    listed = ", ".join(f"{a}-{b} {force / 1e3:.4g} kN" for a, b, force in contacts[:8])
    more = f" and {len(contacts) - 8} more" if len(contacts) > 8 else ""
    total = sum(force for _, _, force in contacts)
    how = ("the equilibrium start counts them ([initial] start_contacts = \"include\")" if counted else
           "the equilibrium start and check leave them out, as hand statics would ([initial] start_contacts = "
           "\"include\" counts them in MuJoCo mode), so they push the machine from the first step; if they are "
           "overlapping meshes of the machine's own links, exclude the pairs with <contact><exclude>")
    return [f"start pose: {len(contacts)} contact(s) touch ({listed}{more}; {total / 1e3:.4g} kN in all): {how}"]


def closure_gap_warnings(scene, qpos, dt) -> list:
    """Warnings for ``connect`` closures that MuJoCo's soft equality lets open by more than :data:`CLOSURE_GAP_WARN` at
    the start pose under the static load (:func:`sim.plants.constraints.closure_gaps`), each with the gap that
    ``solref`` = (:data:`STIFF_SOLREF_STEPS`·dt, 1) and ``solimp`` = :data:`STIFF_SOLIMP` would leave."""
    m = scene.mjmodel
    moments = lambda d: actuator_moments(m, d, scene.binding.actuator_id)  # noqa: E731
    gaps = closure_gaps(m, qpos, moments)
    wide = {name: value for name, value in gaps.items() if value[0] > CLOSURE_GAP_WARN}
    if not wide:
        return []
    solref, solimp = m.eq_solref, m.eq_solimp
    stiffened = copy.copy(m)  # the scene's model is left as it is
    stiffened.eq_solref[:] = (STIFF_SOLREF_STEPS * dt, 1.0)
    stiffened.eq_solimp[:] = STIFF_SOLIMP
    stiff = closure_gaps(stiffened, qpos, lambda d: actuator_moments(stiffened, d, scene.binding.actuator_id))
    out = []
    for name, (gap, force) in wide.items():
        e = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_EQUALITY, name)
        now = (f' (solref="{" ".join(f"{v:g}" for v in solref[e])}" solimp="{" ".join(f"{v:g}" for v in solimp[e, :3])}")'
               if e >= 0 else "")
        out.append(
            f"equality '{name}': MuJoCo's soft constraint{now} opens {gap * 1e3:.3g} mm under its {force / 1e3:.3g} kN at the "
            f"start pose (more than {CLOSURE_GAP_WARN * 1e3:g} mm), and the machine sags with it while its pressures look "
            f'plausible; solref="{STIFF_SOLREF_STEPS * dt:g} 1" solimp="{" ".join(f"{v:g}" for v in STIFF_SOLIMP[:3])}" on it '
            f"leaves {stiff.get(name, (math.nan,))[0] * 1e3:.3g} mm, or drive the cylinder on the rod's slide joint (its pins "
            "then sit on the links and the closure carries only the rod's weight)"
        )
    return out


def relief_limits(network, net_state) -> list:
    """Forward-Euler limit 2/(G·Σ β_eff/V) [s] of every relief valve over its free end nodes (see module docstring).

    Returns a list of (relief name, node names joined by '/', V [m³] of the
    smaller end, β_eff [Pa] there, G [m³/(s·Pa)], limit [s]).
    """
    s = network.relief_branches
    beta = network.effective_bulk_modulus(net_state.node_pressure, net_state.actuator_position)
    volume, _ = network.node_volume_at(net_state.actuator_position, net_state.node_pressure)
    out = []
    for b in range(s.start, s.stop):
        gradient = float(network.relief_gradient[b - s.start])
        ends = [n for n in (network.branch_from[b], network.branch_to[b]) if not network.node_fixed[n]]
        if not ends or gradient <= 0:
            continue
        rate = gradient * sum(float(beta[n]) / float(volume[n]) for n in ends)
        small = min(ends, key=lambda n: float(volume[n]))
        out.append((network.branch_names[b], "/".join(network.node_names[n] for n in ends), float(volume[small]),
                    float(beta[small]), gradient, 2.0 / rate))
    return out


def check_initial_state(plant) -> None:
    """Raise :class:`~sim.io.scenario.ScenarioError` when a freshly built plant's state is not finite at t = 0.

    The loaders reject the known causes with their own field (joint range, chamber
    volume at the start pose, fluid and component ranges); this is the backstop for the
    rest, naming the first non-finite node or joint and the files to look at.
    """
    from sim.io.scenario import ScenarioError

    scenario, net = plant.scene.scenario, plant.network
    p = np.asarray(plant.net_state.node_pressure, float)
    q, qd = plant.joint_state()
    effort = np.asarray(getattr(plant, "effort", np.zeros(0)), float)
    bad_nodes = np.flatnonzero(~np.isfinite(p))
    if len(bad_nodes):
        name = net.node_names[bad_nodes[0]]
        field_name = f"field 'initial.pressures.{name}'" if name in scenario.pressures else "[initial]"
        raise ScenarioError(
            f"{scenario.path}, {field_name}: the initial pressure of node '{name}' is {p[bad_nodes[0]]} Pa (not finite) at the "
            f"start pose; check the initial joint values and pressures, and the volumes and fluid in {scenario.circuit}"
        )
    bad_joints = np.flatnonzero(~(np.isfinite(q) & np.isfinite(qd)))
    if len(bad_joints):
        name = plant.joint_names[bad_joints[0]]
        raise ScenarioError(f"{scenario.path}, field 'initial.qpos.{name}': the initial state of joint '{name}' is not finite ({scenario.mjcf})")
    bad = np.flatnonzero(~np.isfinite(effort))
    if len(bad):
        name = net.actuator_names[bad[0]]
        raise ScenarioError(
            f"{scenario.circuit}: component '{name}': its initial effort is not finite; check its parameters and the initial "
            f"pressures in {scenario.path}"
        )


def check_plant(plant) -> GuardReport:
    """Guard report of a freshly built plant (MuJoCo or PBD) at its initial state.

    Raises :class:`~sim.io.scenario.ScenarioError` (bad input, exit status 2) when that state
    is not finite (:func:`check_initial_state`); otherwise it only warns.
    """
    check_initial_state(plant)
    report = check(plant.scene, plant.net_state)
    residual = getattr(plant, "holding_residual", None)
    if residual is not None and residual > HOLDING_RESIDUAL_WARN:
        from dataclasses import replace

        report = replace(report, warnings=report.warnings + (
            f"{plant.scene.scenario.path}, field 'initial.equilibrium': the actuators and the MJCF's equality constraints cannot "
            f"hold the start pose at rest (static balance residual {residual:.3g} of the load); the start is not in equilibrium: "
            "check the pose and that every loaded joint is driven or closed by a loop",))
    return report


def check_scenario(scenario, *, overrides: dict | None = None) -> GuardReport:
    """Load a scenario (path or Scenario), build its initial state and return its guard report.

    The initial network state comes from a MuJoCo plant of the same scene
    (the pose, inertia and equilibrium pressures do not depend on the mode).
    """
    from sim.plants.mujoco import MujocoPlant
    from sim.io.scenario import Scenario, load_scenario
    from sim.io.scene import load_scene

    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    if overrides:
        scenario = scenario.with_overrides(**overrides)
    probe = scenario.with_overrides(mode="mujoco") if scenario.mode != "mujoco" else scenario
    scene = load_scene(probe)
    plant = MujocoPlant(scene)
    return check(scene, plant.net_state, mode=scenario.mode, coupling=scenario.coupling, dt=scenario.dt)


__all__ = [
    "EXPLICIT_OMEGA_DT_LIMIT", "GuardReport", "GuardRow", "check", "check_plant", "check_scenario",
    "expected_stable", "inertia_seen", "method_name", "oil_column_stiffness", "relief_limits",
]
