"""``hydroplant inspect SCENARIO``: what a scenario will build, and whether its step is stable.

Prints the bodies and joints, the circuit at its fidelity (hydraulic state
count, what was pruned), the MJCF actuators the circuit does not drive, the
equality constraints the statics and inertias go through, in PBD mode the path
that steps it (:func:`sim.plants.pbd.fast_path`), each cylinder's bore, rod and stroke with its
hydraulic frequency ω_h at mid-stroke and at 5 % stroke (the stiffest
position of a typical working range), ω_h·dt and the stability verdict of the
chosen mode and coupling (:mod:`sim.run.guards`), and the largest dt that method
keeps stable.
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np

from hydraulics.network import ACTUATOR_CYLINDER

from sim.run import guards
from sim.plants.mujoco import MujocoPlant
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene

NEAR_END = 0.05  # fraction of stroke of the "near the end" position


def at_positions(plant, fractions):
    """Network states with every cylinder at ``fraction`` of its stroke, pressures as at t = 0."""
    net = plant.network
    states = []
    for fraction in fractions:
        x = plant.net_state.actuator_position.copy()
        x[net.cylinder_actuator] = fraction * net.cylinder_stroke
        states.append(net.state(actuator_position=x, node_pressure=plant.net_state.node_pressure))
    return states


def largest_stable_dt(report: guards.GuardReport) -> float:
    """Largest dt [s] the report's method keeps every actuator stable (inf for implicit schemes, unless rigid
    actuators' supply columns bound it)."""
    if report.method not in guards.EXPLICIT_METHODS:
        return min((r.explicit_max_dt for r in report.rows if r.rigid), default=math.inf)
    return min((r.explicit_max_dt for r in report.rows), default=math.inf)


def describe(scenario_path, overrides=None) -> str:
    """The inspect text for a scenario."""
    return inspect_scenario(scenario_path, overrides)[0]


def inspect_scenario(scenario_path, overrides=None) -> tuple[str, dict]:
    """The inspect text for a scenario and the same facts as the ``inspect --json`` document (SI units)."""
    from sim.methods import Method

    scenario = load_scenario(scenario_path)
    if overrides:
        scenario = scenario.with_overrides(**overrides)
    scene = load_scene(scenario)
    plant = MujocoPlant(scene)
    m, net = scene.mjmodel, scene.network
    lines = [f"scenario  {scenario.path}", f"run       mode {scenario.mode}, coupling {scenario.coupling}, dt {scenario.dt:g} s, fidelity {scenario.fidelity_label}"]
    data = {"scenario": str(scenario.path), "method": Method(scenario.mode, scenario.coupling, scenario.pbd_blend).name,
            "mode": scenario.mode, "coupling": scenario.coupling, "dt_s": scenario.dt, "fidelity": scenario.fidelity_label,
            "total_mass_kg": float(np.sum(m.body_mass)),
            "bodies": [{"name": mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) or f"body{b}", "mass_kg": float(m.body_mass[b])}
                       for b in range(1, m.nbody)],
            "joints": [], "hydraulic_states": int(net.state_count), "nodes": int(net.node_count),
            "flow_branches": len(net.branch_names), "pruned": list(net.pruned), "actuators": []}
    lines.append(f"bodies    {m.nbody - 1} (+ world), total mass {float(np.sum(m.body_mass)):.1f} kg")
    for b in range(1, m.nbody):
        lines.append(f"  {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) or f'body{b}':<20s} {m.body_mass[b]:10.2f} kg")
    lines.append(f"joints    {m.njnt}")
    for j in range(m.njnt):
        kind = mujoco.mjtJoint(int(m.jnt_type[j])).name.removeprefix("mjJNT_").lower()
        limits = f"[{m.jnt_range[j][0]:.4g}, {m.jnt_range[j][1]:.4g}]" if m.jnt_limited[j] else "unlimited"
        lines.append(f"  {scene.joint_names[j]:<20s} {kind:<6s} {limits}")
        data["joints"].append({"name": scene.joint_names[j], "type": kind,
                               "range": [float(m.jnt_range[j][0]), float(m.jnt_range[j][1])] if m.jnt_limited[j] else None})
    contact = not (m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT)
    lines.append(f"contact   {'on' if contact else 'off (no two geoms can touch)'}")
    lines.append(
        f"circuit   {Path(scenario.circuit).name}: fidelity {net.fidelity}, {net.node_count} nodes, "
        f"{net.state_count} hydraulic states, {len(net.branch_names)} flow branches"
    )
    if len(set(net.actuator_fidelity)) > 1:
        lines.append("fidelity  " + ", ".join(f"{a} {lv}" for a, lv in zip(net.actuator_names, net.actuator_fidelity)))
    if net.hose_lines:
        lines.append(f"lines     {', '.join(net.hose_lines)} (pi-lines: own end volumes + laminar resistance)")
    lines.append(f"pruned    {', '.join(net.pruned) if net.pruned else 'nothing'}")
    bound = set(int(i) for i in scene.binding.actuator_id)
    undriven = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a) or f"#{a}" for a in range(m.nu) if a not in bound]
    lines.append(f"undriven  {', '.join(undriven) + ' (MJCF actuators the circuit does not drive: zero force)' if undriven else 'none'}")
    if m.neq:
        from sim.plants.constraints import equality_name

        kinds = [f"{equality_name(m, e)} ({mujoco.mjtEq(int(m.eq_type[e])).name.removeprefix('mjEQ_').lower()})" for e in range(m.neq)]
        lines.append(f"equality  {', '.join(kinds)}: holding efforts and m_eff through them"
                     + (f"; static balance residual {plant.holding_residual:.2g}" if plant.holding_residual is not None else ""))
    if scenario.mode in ("pbd", "pbd-naive"):
        from sim.plants.pbd import fast_path, make_pbd_plant

        lines.append(f"pbd path  {fast_path(make_pbd_plant(scene))}")
    mid, end = at_positions(plant, (0.5, NEAR_END))
    report_mid = guards.check(scene, mid)
    report_end = guards.check(scene, end)
    if report_mid.rows:
        lines.append(
            f"{'actuator':<14s} {'bore/D':>9s} {'rod':>7s} {'stroke':>7s} {'f_h mid':>9s} {'f_h 5%':>9s} "
            f"{'w_h*dt mid':>11s} {'w_h*dt 5%':>10s} {'stable':>7s}"
        )
        for a, (rm, re) in enumerate(zip(report_mid.rows, report_end.rows)):
            if net.actuator_kind[a] == ACTUATOR_CYLINDER:
                c = scene.network.circuit.component(rm.actuator).params
                size = f"{c.bore * 1e3:7.1f}mm {c.rod_diameter * 1e3:5.1f}mm {c.stroke:6.3f}m"
            else:
                c = scene.network.circuit.component(rm.actuator).params
                size = f"{c.displacement * 1e6:6.1f}cc/rev {'':>13s}"
            lines.append(
                f"{rm.actuator:<14s} {size} {rm.frequency_hz:7.3g}Hz {re.frequency_hz:7.3g}Hz "
                f"{rm.omega_h_dt:11.3g} {re.omega_h_dt:10.3g} {'yes' if rm.stable and re.stable else 'NO':>7s}"
            )
            data["actuators"].append({
                "name": rm.actuator, "kind": "cylinder" if net.actuator_kind[a] == ACTUATOR_CYLINDER else "motor",
                "frequency_mid_hz": float(rm.frequency_hz), "frequency_near_end_hz": float(re.frequency_hz),
                "omega_h_dt_mid": float(rm.omega_h_dt), "omega_h_dt_near_end": float(re.omega_h_dt),
                "stable": bool(rm.stable and re.stable)})
    dt_max = min(largest_stable_dt(report_mid), largest_stable_dt(report_end))
    lines.append(
        f"largest stable dt for {report_mid.method}: "
        + ("unbounded by the oil columns (implicit)" if math.isinf(dt_max) else f"{dt_max:.3g} s"
           + (" (the rigid actuators' supply column)" if report_mid.method not in guards.EXPLICIT_METHODS else ""))
    )
    for w in dict.fromkeys(report_mid.warnings + report_end.warnings):
        lines.append(f"warning: {w}")
    for n in dict.fromkeys(report_mid.notes + report_end.notes):
        lines.append(f"note: {n}")
    data.update(guard_method=report_mid.method, largest_stable_dt_s=dt_max,  # inf (null in JSON): unbounded
                warnings=list(dict.fromkeys(report_mid.warnings + report_end.warnings)),
                notes=list(dict.fromkeys(report_mid.notes + report_end.notes)))
    return "\n".join(lines), data


def add_parser(subparsers):
    """Register ``hydroplant inspect`` (declared in :func:`sim.commands.add_inspect`)."""
    from sim.commands import add_inspect

    return add_inspect(subparsers)


def main(args) -> int:
    """``hydroplant inspect``: the text (or with ``--json`` the document) of :func:`inspect_scenario`; exit 0."""
    from sim.cli import method_overrides, scenario_argument

    scenario = scenario_argument(args, "inspect")
    overrides = {**method_overrides(args), "dt": args.dt}
    text, data = inspect_scenario(scenario, {k: v for k, v in overrides.items() if v is not None})
    if getattr(args, "json", False):
        from sim.jsonout import emit

        emit({"command": "inspect", "status": "ok", "exit_code": 0, **data})
    else:
        print(text)
    return 0
