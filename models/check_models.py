"""Static checks of the scenes in models/ (run: .venv/bin/python models/check_models.py).

For every scene: compiles the MJCF, checks each cylinder tendon against its circuit
component (stroke == LMAX - LMIN), sweeps each driving joint across its range and checks
the tendon stays inside [LMIN, LMAX], prints tendon lengths and moment arms at the initial
pose and at both stroke ends, and (with gravity) the static cylinder force / pressure needed
to hold the initial pose (mj_inverse with qacc = 0, solved through the actuator moments).
Numbers printed here are the ones quoted in each scene's README.md.
"""
from __future__ import annotations

import math
import pathlib
import tomllib

import mujoco
import numpy as np

HERE = pathlib.Path(__file__).resolve().parent


def dense_moment(m, d):
    """Actuator moment matrix (nu x nv), densified from MuJoCo's sparse storage."""
    M = np.zeros((m.nu, m.nv))
    for i in range(m.nu):
        a, n = d.moment_rowadr[i], d.moment_rownnz[i]
        M[i, d.moment_colind[a:a + n]] = d.actuator_moment[a:a + n]
    return M


def set_qpos(m, d, qpos: dict):
    d.qpos[:] = m.qpos0
    for name, v in qpos.items():
        d.qpos[m.jnt_qposadr[m.joint(name).id]] = v
    d.qvel[:] = 0
    mujoco.mj_forward(m, d)
    d.qacc[:] = 0  # so that a following mj_inverse gives the static holding forces


def load_scene(scenario: pathlib.Path):
    sc = tomllib.loads(scenario.read_text())
    mjcf = scenario.parent / sc["scene"]["mjcf"]
    circ = tomllib.loads((scenario.parent / sc["scene"]["circuit"]).read_text())
    comps = {c["name"]: c for c in circ["component"]}
    return sc, mjcf, circ, comps


def areas(c):
    a_cap = math.pi / 4 * c["bore"] ** 2
    return a_cap, a_cap - math.pi / 4 * c["rod_diameter"] ** 2


def check(scenario: pathlib.Path, relief_name: str | None):
    sc, mjcf, circ, comps = load_scene(scenario)
    m = mujoco.MjModel.from_xml_path(str(mjcf))
    d = mujoco.MjData(m)
    q0 = sc["initial"]["qpos"]
    print(f"\n=== {scenario.relative_to(HERE)}  ({mjcf.name}: nq={m.nq} nu={m.nu}, "
          f"total mass {m.body_mass.sum():.0f} kg)")
    set_qpos(m, d, q0)
    M0 = dense_moment(m, d)
    ok = True
    for t in range(m.ntendon):
        name = m.tendon(t).name
        c = comps[name]
        lo, hi = m.tendon_range[t]
        if abs((hi - lo) - c["stroke"]) > 1e-9:
            print(f"  !! {name}: tendon span {hi - lo} != circuit stroke {c['stroke']}")
            ok = False
        act = m.actuator(name).id
        dof = int(np.argmax(np.abs(M0[act])))
        jnt = m.dof_jntid[dof]
        jname = m.joint(jnt).name
        L0, arm0 = d.ten_length[t], M0[act, dof]
        print(f"  {name}: LMIN {lo:.4f} LMAX {hi:.4f} stroke {c['stroke']} m | initial "
              f"L = {L0:.4f} m ({(L0 - lo) / (hi - lo) * 100:.1f} % stroke), dL/d{jname} = {arm0:+.4f} m"
              + ("" if lo <= L0 <= hi or not m.tendon_limited[t] else "  !! OUTSIDE RANGE"))
        if m.tendon_limited[t] and not lo <= L0 <= hi:
            ok = False
        if not m.jnt_limited[jnt]:
            continue
        # sweep the driving joint across its range, others at the initial pose
        jlo, jhi = m.jnt_range[jnt]
        Ls, arms = [], []
        for q in np.linspace(jlo, jhi, 201):
            set_qpos(m, d, {**q0, jname: q})
            Ls.append(d.ten_length[t])
            arms.append(dense_moment(m, d)[act, dof])
        Ls, arms = np.array(Ls), np.array(arms)
        inside = (Ls.min() >= lo - 1e-6) and (Ls.max() <= hi + 1e-6)
        ok &= inside
        print(f"    sweep {jname} [{jlo:+.4f}, {jhi:+.4f}] rad = [{math.degrees(jlo):+.1f}, "
              f"{math.degrees(jhi):+.1f}] deg: L in [{Ls.min():.4f}, {Ls.max():.4f}] "
              f"{'inside' if inside else '!! OUTSIDE'}; moment arm at ends "
              f"{arms[0]:+.4f} / {arms[-1]:+.4f} m, min {arms.min():+.4f} m, monotone "
              f"{bool(np.all(np.diff(Ls) > 0) or np.all(np.diff(Ls) < 0))}")
    # static holding forces at the initial pose (gravity on, qvel = qacc = 0, no contacts)
    set_qpos(m, d, q0)
    if d.ncon:
        print(f"  !! {d.ncon} contacts at the initial pose")
    mujoco.mj_inverse(m, d)
    M = dense_moment(m, d)
    f, *_ = np.linalg.lstsq(M.T, d.qfrc_inverse, rcond=None)
    resid = np.abs(M.T @ f - d.qfrc_inverse).max()
    relief = comps[relief_name]["cracking_pressure"] if relief_name else None
    print(f"  static hold at initial pose (residual {resid:.2e}):")
    for i in range(m.nu):
        name = m.actuator(i).name
        c = comps.get(name, {})
        if c.get("type") == "cylinder":
            a_cap, a_ann = areas(c)
            p = f[i] / a_cap if f[i] >= 0 else -f[i] / a_ann
            side = "cap" if f[i] >= 0 else "rod"
            frac = f" = {p / relief * 100:.0f} % of relief" if relief else ""
            print(f"    {name}: F = {f[i] / 1e3:+.2f} kN -> {side} pressure {p / 1e5:.1f} bar gauge{frac}")
        elif c.get("type") == "motor":
            print(f"    {name}: torque {f[i]:+.1f} N m")
    # sign check: a positive actuator force alone (gravity off, at rest) accelerates its joint +
    g = m.opt.gravity.copy()
    m.opt.gravity[:] = 0
    for i in range(m.nu):
        set_qpos(m, d, q0)
        d.ctrl[:] = 0
        d.ctrl[i] = 1.0e3
        mujoco.mj_forward(m, d)
        dof = int(np.argmax(np.abs(dense_moment(m, d)[i])))
        tip = ""
        if "tooth_tip" in [m.site(k).name for k in range(m.nsite)]:
            # tooth-tip velocity per unit rate of this joint (world x fwd, z up at swing = 0)
            jac = np.zeros((3, m.nv))
            mujoco.mj_jacSite(m, d, jac, None, m.site("tooth_tip").id)
            a = jac[:, dof]
            tip = f"; d(tooth tip)/dq = ({a[0]:+.2f}, {a[1]:+.2f}, {a[2]:+.2f}) m/rad"
        print(f"  sign: +1 kN on {m.actuator(i).name} -> qacc[{m.joint(m.dof_jntid[dof]).name}] = "
              f"{d.qacc[dof]:+.4g}{tip}")
    d.ctrl[:] = 0
    m.opt.gravity[:] = g
    return ok, m, d


def worst_case_excavator(scenario):
    """Holding pressures over a grid of poses (teeth above ground): the lifting margin."""
    sc, mjcf, circ, comps = load_scene(scenario)
    m = mujoco.MjModel.from_xml_path(str(mjcf))
    d = mujoco.MjData(m)
    relief = comps["main_relief"]["cracking_pressure"]
    worst = {}
    rng = {n: m.jnt_range[m.joint(n).id] for n in ("boom", "stick", "bucket")}
    for qb in np.linspace(*rng["boom"], 15):
        for qs in np.linspace(*rng["stick"], 15):
            for qk in np.linspace(*rng["bucket"], 9):
                set_qpos(m, d, {"boom": qb, "stick": qs, "bucket": qk})
                if d.nefc:  # skip poses with contacts or active limits (they add constraint forces)
                    continue
                mujoco.mj_inverse(m, d)
                f, *_ = np.linalg.lstsq(dense_moment(m, d).T, d.qfrc_inverse, rcond=None)
                for i, name in enumerate(("boom_cyl", "stick_cyl", "bucket_cyl")):
                    a_cap, a_ann = areas(comps[name])
                    p = f[i] / a_cap if f[i] >= 0 else -f[i] / a_ann
                    if p > worst.get(name, (0,))[0]:
                        worst[name] = (p, "cap" if f[i] >= 0 else "rod", (qb, qs, qk))
    print("\n  excavator worst-case static holding pressure over the joint-range grid (teeth above ground):")
    for name, (p, side, q) in worst.items():
        print(f"    {name}: {p / 1e5:.0f} bar ({side}) = {p / relief * 100:.0f} % of relief at "
              f"boom/stick/bucket = {q[0]:+.2f}/{q[1]:+.2f}/{q[2]:+.2f} rad")


def main():
    all_ok = True
    for scen, relief in [
        (HERE / "seed_cylinder" / "closed.scenario.toml", None),
        (HERE / "boom" / "hold.scenario.toml", "relief"),
        (HERE / "excavator" / "dig.scenario.toml", "main_relief"),
    ]:
        if not scen.exists():
            print(f"(missing {scen})")
            continue
        ok, m, d = check(scen, relief)
        all_ok &= ok
    exc = HERE / "excavator" / "dig.scenario.toml"
    if exc.exists():
        worst_case_excavator(exc)
    print("\nALL OK" if all_ok else "\n!! SOME CHECKS FAILED")
    return 0 if all_ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
