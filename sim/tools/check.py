"""``hydroplant check SCENARIO``: static checks of any scene before it is run.

For the scenario's scene (the MJCF bound to its circuit, validated as for a run):

* **equalities**: each loop closure's violation at the pose the scenario sets and
  after the start pose is projected onto the constraints (:func:`sim.io.scene.initial_qpos_qvel`);
* **cylinders**: tendon range [LMIN, LMAX] against the circuit's stroke, the pin-to-pin
  length L and its moment arm dL/dq on the cylinder's driving joint at the start pose
  and at both stroke ends; the driving joint is the joint (limited ones first) that
  moves L most, not counting the joints of the cylinder's own barrel and rod bodies in
  a loop, every other joint held except those the loop closures move; a sweep of that joint across its range (the loops closed at every point)
  must keep L inside [LMIN, LMAX];
* **holding**: the static efforts at the start pose and the stroke ends with the
  loop closures carrying their share (:func:`sim.plants.constraints.holding_efforts`), as
  chamber pressure against the highest relief setting on that chamber's side (or the
  circuit's highest relief);
* **signs**: with gravity off, a positive effort on each actuator alone must extend it
  (J·q̈ > 0) and moves its driving joint, and the valve whose work port A reaches the
  cylinder's cap (through hoses) extends it on a positive command.

Problems are marked ``!!`` and make the exit status 1; bad input exits 2.
Example::

    hydroplant check models/excavator/dig.scenario.toml
    hydroplant check --examples            every shipped scene
    hydroplant check --grid 15 SCENARIO    also the worst holding pressures over the joint ranges
    hydroplant check --mode pbd SCENARIO   with PBD mode's warnings and refusals
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np

from hydraulics.network import ACTUATOR_CYLINDER

from sim.io.examples import example_path, examples
from sim.io.scenario import ScenarioError, load_scenario
from sim.io.scene import initial_qpos_qvel, load_scene
from sim.plants.constraints import actuator_moments, equality_rows, holding_efforts, project_pose
from sim.run.guards import start_contact_warnings

SWEEP_POINTS = 101  # points of a joint-range sweep
LENGTH_TOLERANCE = 1e-4  # m: L may pass LMIN/LMAX by this much in a sweep (ranges rounded in the MJCF)
PROBE = 1e-5  # rad or m: joint perturbation that finds the driving joint


class Checker:
    """The scene of one scenario and the kinematic helpers of the checks."""

    def __init__(self, scenario_path, mode=None):
        self.scenario = load_scenario(scenario_path)
        if mode:
            self.scenario = self.scenario.with_overrides(mode=mode)
        self.scene = load_scene(self.scenario)
        self.m = self.scene.mjmodel
        self.d = mujoco.MjData(self.m)
        self.q0, _ = initial_qpos_qvel(self.scene)
        self.contacts = self.scenario.start_contacts == "include"  # start-pose contacts carry load in the holding efforts
        G = self.equalities(self.q0)[0]
        self.loop_dofs = np.any(np.abs(G) > 0, axis=0) if len(G) else np.zeros(self.m.nv, bool)
        self.problems = 0

    def forward(self, qpos):
        self.d.qpos[:] = qpos
        self.d.qvel[:] = 0.0
        mujoco.mj_forward(self.m, self.d)
        return self.d

    def equalities(self, qpos):
        return equality_rows(self.m, self.forward(qpos))

    def pose(self, dof, value):
        """The start pose with DOF(s) ``dof`` at ``value`` and the loops closed by the loop DOFs (None if they cannot)."""
        m = self.m
        q = self.q0.copy()
        dofs, values = np.atleast_1d(dof), np.atleast_1d(value)
        q[m.jnt_qposadr[m.dof_jntid[dofs]]] = values
        held = ~self.loop_dofs
        held[dofs] = True
        try:
            q, _, _ = project_pose(m, q, np.zeros(m.nv), held)
        except ScenarioError:
            return None
        return q

    def lengths(self, qpos):
        d = self.forward(qpos)
        return np.array(d.actuator_length[self.scene.binding.actuator_id])

    def note(self, ok: bool) -> str:
        if not ok:
            self.problems += 1
        return "" if ok else "  !!"


def scalar_dofs(m) -> list:
    """DOFs of hinge and slide joints."""
    kinds = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    return [int(m.jnt_dofadr[j]) for j in range(m.njnt) if int(m.jnt_type[j]) in kinds]


def joint_name(m, dof: int) -> str:
    return mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, int(m.dof_jntid[dof])) or f"dof{dof}"


def driving_joint(ck: Checker, a: int):
    """(dof, dL/dq) of the joint outside the actuator's own bodies that moves its length most along the loops
    (limited joints first: their range is what the sweep checks)."""
    m, scene = ck.m, ck.scene
    tid = int(scene.binding.tendon_id[a])
    mine = set()  # barrel/rod pairs: a slide in a loop and the body it slides in, wherever the tendon's sites sit
    for dof in scalar_dofs(m):
        if ck.loop_dofs[dof] and int(m.jnt_type[m.dof_jntid[dof]]) == int(mujoco.mjtJoint.mjJNT_SLIDE):
            mine |= {int(m.dof_bodyid[dof]), int(m.body_parentid[m.dof_bodyid[dof]])}
    best = (None, 0.0, False)
    for dof in scalar_dofs(m):
        if tid < 0:
            if dof == int(m.jnt_dofadr[m.actuator_trnid[scene.binding.actuator_id[a], 0]]):
                return dof, float(m.actuator_gear[scene.binding.actuator_id[a], 0])
            continue
        if int(m.dof_bodyid[dof]) in mine:
            continue  # a cylinder's own barrel or rod joint, closed onto the links by the loop
        value = ck.q0[m.jnt_qposadr[m.dof_jntid[dof]]]
        plus, minus = ck.pose(dof, value + PROBE), ck.pose(dof, value - PROBE)
        if plus is None or minus is None:
            continue
        arm = (ck.lengths(plus)[a] - ck.lengths(minus)[a]) / (2 * PROBE)
        limited = bool(m.jnt_limited[m.dof_jntid[dof]])
        if abs(arm) > 1e-9 and ((limited, abs(arm)) > (best[2], abs(best[1]))):
            best = (dof, float(arm), limited)
    return best[:2]


def hose_joined(circuit, net) -> set:
    """The nets joined to ``net`` through hoses (a hose has the same pressure at both ends), ``net`` included.

    Example: ``hose_joined(circuit, valve.ports["A"])`` holds the chamber nets the valve's A port feeds.
    """
    nets, changed = {net}, True
    while changed:
        changed = False
        for c in circuit.by_kind("hose"):
            ends = set(c.ports.values())
            if ends & nets and not ends <= nets:
                nets |= ends
                changed = True
    return nets


def relief_for(scene, a: int, side: str) -> tuple:
    """(name, cracking pressure [Pa]) of the relief on the chamber's net, else the circuit's highest relief."""
    circuit = scene.network.circuit
    chamber = circuit.component(scene.network.actuator_names[a]).ports.get(side)
    reliefs = circuit.by_kind("relief_valve")
    nets = hose_joined(circuit, chamber)
    on_side = [r for r in reliefs if r.ports.get("inlet") in nets]
    pick = on_side or reliefs
    if not pick:
        return None, math.inf
    best = max(pick, key=lambda r: r.params.cracking_pressure)
    return best.name, float(best.params.cracking_pressure)


def valve_for(scene, a: int):
    """(valve name, +1 if its A port reaches the cap chamber, −1 if the rod chamber) through hoses, or (None, 0)."""
    circuit = scene.network.circuit
    cyl = circuit.component(scene.network.actuator_names[a])
    for valve in circuit.by_kind("valve_4_3"):
        for port, sign in (("A", 1), ("B", -1)):
            nets = hose_joined(circuit, valve.ports[port])
            if cyl.ports.get("cap") in nets:
                return valve.name, sign
            if cyl.ports.get("rod") in nets:
                return valve.name, -sign
    return None, 0


END_BISECTIONS = 60  # halvings of a sweep interval when finding a stroke end (to round-off)


def stroke_end(ck: Checker, a: int, dof: int, values, lengths, k: int, target: float) -> tuple[float, float]:
    """(driving-joint value, L) where actuator ``a``'s length L equals ``target`` [m], bisected between the sweep
    point ``k`` nearest to it and the neighbour on the other side of it; the sweep point itself when L does not
    cross ``target`` there (the joint's range ends before the stroke does).  A pose between sweep points, not the
    nearest point, so that a stroke end is never evaluated past the end stop."""
    for j in (k - 1, k + 1):
        if 0 <= j < len(values) and np.isfinite(lengths[j]) and (lengths[k] - target) * (lengths[j] - target) < 0:
            lo, hi, f_lo = float(values[k]), float(values[j]), float(lengths[k] - target)
            for _ in range(END_BISECTIONS):
                mid = 0.5 * (lo + hi)
                q = ck.pose(dof, mid)
                if q is None:  # the loops do not close there: keep the bracket found so far
                    break
                f_mid = float(ck.lengths(q)[a] - target)
                if (f_mid > 0) == (f_lo > 0):
                    lo, f_lo = mid, f_mid
                else:
                    hi = mid
            return lo, target + f_lo
    return float(values[k]), float(lengths[k])


def pressure_text(ck: Checker, a: int, effort: float) -> str:
    """Holding effort as chamber pressure against the relief on that side."""
    net = ck.scene.network
    name = net.actuator_names[a]
    if net.actuator_kind[a] != ACTUATOR_CYLINDER:
        return f"{name}: torque {effort:+.4g} N*m"
    i = list(net.cylinder_actuator).index(a)
    side = "cap" if effort >= 0 else "rod"
    area = net.cylinder_cap_area[i] if effort >= 0 else net.cylinder_rod_area[i]
    p = abs(effort) / area
    relief, limit = relief_for(ck.scene, a, side)
    share = p / limit if math.isfinite(limit) else 0.0
    flag = ck.note(share <= 1.0)
    against = f" = {share * 100:.0f} % of relief '{relief}' ({limit / 1e5:.0f} bar)" if relief else ""
    return f"{name}: F = {effort / 1e3:+.3f} kN -> {side} {p / 1e5:.1f} bar gauge{against}{flag}"


GRID_POSES_MAX = 20000  # poses of a --grid scan at most (fewer points per joint beyond)


def worst_holding(ck: Checker, points: int) -> list:
    """Highest static holding pressure of each cylinder over a grid of its driving joints' ranges (no contacts)."""
    m, net = ck.m, ck.scene.network
    ids = ck.scene.binding.actuator_id
    dofs = sorted({d for a in range(net.actuator_count) if net.actuator_kind[a] == ACTUATOR_CYLINDER
                   for d in [driving_joint(ck, a)[0]] if d is not None and m.jnt_limited[m.dof_jntid[d]]})
    if not dofs:
        return []
    points = max(2, min(points, int(GRID_POSES_MAX ** (1.0 / len(dofs)))))
    axes = [np.linspace(*m.jnt_range[m.dof_jntid[d]], points) for d in dofs]
    worst, skipped = {}, 0
    for values in np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, len(dofs)):
        q = ck.pose(np.array(dofs), values)
        if q is None or ck.forward(q).ncon:
            skipped += 1
            continue
        effort, _ = holding_efforts(m, q, lambda d: actuator_moments(m, d, ids), contacts=ck.contacts)
        for a in range(net.actuator_count):
            if net.actuator_kind[a] != ACTUATOR_CYLINDER:
                continue
            i = list(net.cylinder_actuator).index(a)
            p = effort[a] / net.cylinder_cap_area[i] if effort[a] >= 0 else -effort[a] / net.cylinder_rod_area[i]
            if p > worst.get(a, (-1.0,))[0]:
                worst[a] = (p, float(effort[a]), values)
    names = ", ".join(joint_name(m, d) for d in dofs)
    out = [f"  worst holding over a {points}-point grid of {names} ({skipped} poses in contact or open skipped):"]
    for a, (p, effort, values) in worst.items():
        where = ", ".join(f"{joint_name(m, d)} {v:+.3f}" for d, v in zip(dofs, values))
        out.append(f"    {pressure_text(ck, a, effort)} at {where}")
    return out


def check_scene(scenario_path, grid: int = 0, mode=None) -> tuple[str, int]:
    """The check report of one scenario and its count of problems (``grid``: points per joint of the worst-holding scan,
    0 = off; ``mode`` overrides the scenario's, for that mode's warnings)."""
    ck = Checker(scenario_path, mode)
    m, scene, net = ck.m, ck.scene, ck.scene.network
    out = [f"=== {ck.scenario.path} ({Path(ck.scenario.mjcf).name}: nq {m.nq}, nv {m.nv}, nu {m.nu}, "
           f"total mass {float(np.sum(m.body_mass)):.1f} kg)"]
    out += [f"  warning: {w}" for w in scene.warnings + tuple(start_contact_warnings(scene, ck.q0, ck.scenario.mode))]
    out += [f"  note: {n}" for n in scene.notes]
    if m.neq:
        raw, _ = initial_qpos_qvel(scene, project=False)
        _, before, names = ck.equalities(raw)
        _, after, _ = ck.equalities(ck.q0)
        for name in dict.fromkeys(names):
            rows = [k for k, n in enumerate(names) if n == name]
            b, f = float(np.max(np.abs(before[rows]))), float(np.max(np.abs(after[rows])))
            out.append(f"  equality {name}: violation {b:.3g} at the set pose, {f:.3g} after projection{ck.note(f < 1e-6)}")
    ids = scene.binding.actuator_id
    extremes = []  # (label, qpos) for the holding check
    for a, name in enumerate(net.actuator_names):
        if net.actuator_kind[a] != ACTUATOR_CYLINDER:
            dof, gear = driving_joint(ck, a)
            out.append(f"  {name}: motor on joint '{joint_name(m, dof)}', gear {gear:g}")
            continue
        i = list(net.cylinder_actuator).index(a)
        low = float(scene.binding.closed_length[a])
        stroke = float(net.cylinder_stroke[i])
        high = low + stroke
        length = float(ck.lengths(ck.q0)[a])
        dof, arm = driving_joint(ck, a)
        inside = low - LENGTH_TOLERANCE <= length <= high + LENGTH_TOLERANCE
        out.append(f"  {name}: LMIN {low:.4f} LMAX {high:.4f} m (stroke {stroke:g} m) | start L = {length:.4f} m "
                   f"({(length - low) / stroke * 100:.1f} % stroke)" + (f", dL/d{joint_name(m, dof)} = {arm:+.4f} m" if dof is not None
                                                                      else ", no joint outside its own bodies moves it") + ck.note(inside))
        if dof is None:
            ck.note(False)
            continue
        j = int(m.dof_jntid[dof])
        span = m.jnt_range[j] if m.jnt_limited[j] else ck.q0[m.jnt_qposadr[j]] + np.array([-1.0, 1.0]) * (1.0 if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE else 0.5)
        values = np.linspace(span[0], span[1], SWEEP_POINTS)
        lengths, closed = [], []
        for v in values:
            q = ck.pose(dof, v)
            closed.append(q is not None)
            lengths.append(ck.lengths(q)[a] if q is not None else np.nan)
        lengths = np.array(lengths)
        ok = np.array(closed)
        if not np.any(ok):
            out.append(f"    sweep {joint_name(m, dof)}: the loops do not close anywhere in [{span[0]:+.4f}, {span[1]:+.4f}]{ck.note(False)}")
            continue
        within = bool(np.all((lengths[ok] >= low - LENGTH_TOLERANCE) & (lengths[ok] <= high + LENGTH_TOLERANCE)))
        monotone = bool(np.all(np.diff(lengths[ok]) > 0) or np.all(np.diff(lengths[ok]) < 0))
        out.append(f"    sweep {joint_name(m, dof)} [{span[0]:+.4f}, {span[1]:+.4f}]"
                   + ("" if m.jnt_limited[j] else " (unlimited joint: start ± 1)")
                   + f": L in [{np.nanmin(lengths):.4f}, {np.nanmax(lengths):.4f}] m "
                   + ("inside the stroke" if within else "OUTSIDE the stroke: the joint range reaches past a cylinder end")
                   + f", monotone {monotone}" + ("" if ok.all() else f", loops open at {int((~ok).sum())} of {SWEEP_POINTS} points")
                   + ck.note(within))
        # stroke ends: the driving joint where L = LMIN and L = LMAX (inside the sweep), else the sweep's ends
        for label, target in (("retracted", low), ("extended", high)):
            k = int(np.nanargmin(np.abs(lengths - target)))
            if abs(lengths[k] - target) > 0.01 * stroke:
                out.append(f"    {label}: not reached in the range of {joint_name(m, dof)} (L comes to {lengths[k]:.4f} m at "
                           f"{values[k]:+.4f}): the joint's range ends the motion before the cylinder does")
                continue
            value, length = stroke_end(ck, a, dof, values, lengths, k, target)
            q = ck.pose(dof, value)
            plus, minus = ck.pose(dof, value + PROBE), ck.pose(dof, value - PROBE)
            end_arm = (ck.lengths(plus)[a] - ck.lengths(minus)[a]) / (2 * PROBE) if plus is not None and minus is not None else math.nan
            out.append(f"    {label}: {joint_name(m, dof)} = {value:+.4f}, L = {length:.4f} m, dL/d{joint_name(m, dof)} = {end_arm:+.4f} m")
            extremes.append((f"{name} {label}", q))
    # holding at the start pose and at the stroke ends
    for label, q in [("start pose", ck.q0)] + extremes:
        if q is None:
            continue
        contacts = int(ck.forward(q).ncon)
        if contacts and label != "start pose":
            out.append(f"  holding at {label}: {contacts} contact(s) at this pose (resting on something): not a free hold, skipped")
            continue
        effort, residual = holding_efforts(m, q, lambda d: actuator_moments(m, d, ids), contacts=ck.contacts)
        out.append(f"  holding at {label} (static balance residual {residual:.2g}{ck.note(residual < 1e-6)}):")
        out += [f"    {pressure_text(ck, a, float(effort[a]))}" for a in range(net.actuator_count)]
    if grid:
        out += worst_holding(ck, grid)
    # signs: gravity off, a positive effort alone extends the actuator
    gravity = m.opt.gravity.copy()
    m.opt.gravity[:] = 0.0
    try:
        for a, name in enumerate(net.actuator_names):
            d = ck.forward(ck.q0)
            d.ctrl[:] = 0.0
            d.ctrl[ids[a]] = 1.0e3
            mujoco.mj_forward(m, d)
            J = actuator_moments(m, d, ids)
            rate = float(J[a] @ d.qacc)
            dof, _ = driving_joint(ck, a)
            where = f", q_ddot[{joint_name(m, dof)}] = {d.qacc[dof]:+.4g}" if dof is not None else ""
            valve, sign = valve_for(scene, a) if net.actuator_kind[a] == ACTUATOR_CYLINDER else (None, 0)
            command = f"; valve '{valve}' +1 -> {'extends' if sign > 0 else 'retracts'}" if valve else ""
            out.append(f"  sign: +1 kN on {name} -> its acceleration {rate:+.4g} (m/s^2 or rad/s^2){where}{command}{ck.note(rate > 0)}")
            d.ctrl[:] = 0.0
    finally:
        m.opt.gravity[:] = gravity
    return "\n".join(out), ck.problems


def add_parser(subparsers):
    """Register ``hydroplant check`` (declared in :func:`sim.commands.add_check`)."""
    from sim.commands import add_check

    return add_check(subparsers)


def main(args) -> int:
    """``hydroplant check``; exit 0 when every check passed, 1 when one failed (marked ``!!``)."""
    import sys

    paths = list(args.scenario) + [example_path(name) for name in (getattr(args, "example", None) or [])]
    paths += [example_path(name) for name, _ in examples()] if args.examples else []
    if not paths:
        raise ScenarioError("check: give a SCENARIO file, --example NAME or --examples")
    as_json = getattr(args, "json", False)
    problems = 0
    scenes = []
    for path in paths:
        text, count = check_scene(path, args.grid, args.mode)
        print(text, file=sys.stderr if as_json else sys.stdout)
        problems += count
        lines = text.splitlines()
        scenes.append({"scenario": str(path), "problems": count, "passed": count == 0,
                       "failed_checks": [line.strip().removesuffix("!!").strip() for line in lines if line.endswith("!!")],
                       "report": lines})
    print("\nall checks passed" if not problems else f"\n!! {problems} check(s) failed", file=sys.stderr if as_json else sys.stdout)
    code = 0 if not problems else 1
    if as_json:
        from sim.jsonout import emit

        emit({"command": "check", "status": "ok" if not problems else "failed", "exit_code": code,
              "problems": problems, "scenarios": scenes})
    return code
