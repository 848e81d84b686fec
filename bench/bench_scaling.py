"""Cost per step against machine size: N independent booms, one shared pump or a pump each, in both modes.

The scene (:func:`write_scene`) is N copies of the shipped boom (``models/boom``: a 150 kg boom with a 200 kg
payload lifted by one 63/35 mm cylinder through a closed-centre 4/3 valve and two hoses), side by side 1 m apart
along y, none touching another:

* ``shared``: one pump of N times the boom's displacement, one supply gallery (N times its volume) and one relief
  (N times its gradient) feed all N valves: the supply node joins every boom's valve, the Newton matrix is an
  arrowhead (the booms' blocks bordered by the supply);
* ``each``: every boom has its own pump, supply gallery and relief: N decoupled blocks.

Every valve opens from 0 to +1 over 0.1–0.2 s (the boom lifts at ≈ 0.15 m/s and stays clear of its stops in the
window).  Each size N is timed in both modes from the scene's initial state over ``--window`` simulated seconds
(MuJoCo mode: ``MujocoPlantFast``, coupling implicit, 1 ms steps; PBD mode: ``PbdPlant`` on the runner's block path,
1 ms frames × 1 substep), ``--reps`` rounds, every size once per round in alternation (paired).  Printed: µs per
step (median and quartiles over the rounds), µs per step and actuator, and the scaling exponent
log(t(N₂)/t(N₁))/log(N₂/N₁) between consecutive sizes and over N = 4 → 32, from each round's pair (median and
quartiles).  An exponent of 1 is a cost linear in the number of actuators.  Beside them, ``bare``: plain
``mj_step`` on the same MJCF over the same window with the effort law of the MuJoCo plant's first step held as
constant controls (as ``bench_fast.py``), MuJoCo's own share of MuJoCo mode's step.

    .venv/bin/python bench/bench_scaling.py [--sizes 1 2 4 8 16 32] [--reps 5] [--window 0.3] [--markdown]
"""

from __future__ import annotations

import argparse
import math
import statistics
import tempfile
import time
from pathlib import Path

import mujoco

from sim.io.scenario import load_scenario
from sim.io.scene import load_scene
from sim.run.runner import block_steps, make_plant

DT = 1e-3  # s
LAYOUTS = ("shared", "each")
MODES = ("mujoco", "pbd")
LABELS = {"mujoco": "MuJoCo mode", "pbd": "PBD mode", "bare": "bare `mj_step`"}

_FLUID = """[fluid]
density = 870.0
bulk_modulus = 1.5e9
kinematic_viscosity = 4.6e-5
reference_pressure = 1.01325e5
cavitation_pressure = 3.0e3
air_fraction = 0.0

[[component]]
name = "tank"
type = "tank"
pressure = 1.01325e5
ports = { port = "tank" }
"""

_SUPPLY = """
[[component]]
name = "pump{s}"
type = "pump_fixed"
displacement = {displacement!r}
speed = 40.0
volumetric_efficiency = 0.95
ports = {{ inlet = "tank", outlet = "supply{s}" }}

[[component]]
name = "supply_volume{s}"
type = "volume"
volume = {volume!r}
wall_bulk_modulus = 1.0e9
ports = {{ port = "supply{s}" }}

[[component]]
name = "relief{s}"
type = "relief_valve"
cracking_pressure = 2.0e7
gradient = {gradient!r}
ports = {{ inlet = "supply{s}", outlet = "tank" }}
"""

_BOOM_CIRCUIT = """
[[component]]
name = "valve{i}"
type = "valve_4_3"
max_area = 1.5e-5
centre = "closed"
overlap = 0.1
leakage_area = 1.0e-11
time_constant = 0.03
discharge_coefficient = 0.7
ports = {{ P = "supply{s}", T = "tank", A = "a{i}", B = "b{i}" }}

[[component]]
name = "hose_a{i}"
type = "hose"
length = 2.0
inner_diameter = 0.0127
wall_bulk_modulus = 1.0e9
ports = {{ a = "a{i}", b = "cap{i}" }}

[[component]]
name = "hose_b{i}"
type = "hose"
length = 2.0
inner_diameter = 0.0127
wall_bulk_modulus = 1.0e9
ports = {{ a = "b{i}", b = "rod{i}" }}

[[component]]
name = "cyl{i}"
type = "cylinder"
bore = 0.063
rod_diameter = 0.035
stroke = 0.40
dead_volume_cap = 3.0e-5
dead_volume_rod = 2.2e-5
coulomb_friction = 400.0
static_friction = 500.0
stribeck_velocity = 0.01
viscous_friction = 2000.0
leakage_conductance = 0.0
ports = {{ cap = "cap{i}", rod = "rod{i}" }}
"""

_BOOM_BODY = """
    <site name="barrel{i}" pos="0.05 {y} 1.0" size="0.02"/>
    <body name="boom{i}" pos="0 {y} 1.5">
      <joint name="hinge{i}" type="hinge" axis="0 -1 0" limited="true" range="-0.2448 0.7710" damping="0"/>
      <inertial pos="1.25 0 0" mass="150" diaginertia="0.78 78.1 78.1"/>
      <geom type="box" pos="1.25 0 0" size="1.25 0.075 0.10" contype="0" conaffinity="0" mass="0"/>
      <site name="rod{i}" pos="0.70 0 -0.08" size="0.02"/>
      <body name="payload{i}" pos="2.5 0 0">
        <inertial pos="0 0 -0.2" mass="200" diaginertia="3.0 3.0 3.0"/>
      </body>
    </body>"""


def write_scene(folder: Path, n: int, layout: str) -> Path:
    """MJCF, circuit and scenario of ``n`` booms with one pump (``layout`` "shared") or a pump each ("each") in
    ``folder``; returns the scenario's path."""
    if layout not in LAYOUTS:
        raise ValueError(f"write_scene: layout {layout!r} is not one of {LAYOUTS}")
    bodies = "".join(_BOOM_BODY.format(i=i, y=f"{1.0 * i:.1f}") for i in range(n))
    tendons = "".join(f'\n    <spatial name="cyl{i}" limited="true" range="0.66 1.06" width="0.03">'
                      f'<site site="barrel{i}"/><site site="rod{i}"/></spatial>' for i in range(n))
    actuators = "".join(f'\n    <general name="cyl{i}" tendon="cyl{i}" gaintype="fixed" gainprm="1" biastype="affine" '
                        f'biasprm="0 0 0"/>' for i in range(n))
    (folder / "booms.xml").write_text(
        f'<mujoco model="booms{n}">\n  <compiler angle="radian" autolimits="false"/>\n'
        f'  <option timestep="0.001" integrator="implicitfast" gravity="0 0 -9.81"/>\n'
        f'  <worldbody>{bodies}\n  </worldbody>\n  <tendon>{tendons}\n  </tendon>\n'
        f'  <actuator>{actuators}\n  </actuator>\n</mujoco>\n')
    parts = [_FLUID]
    if layout == "shared":
        parts.append(_SUPPLY.format(s="", displacement=1.2e-5 * n, volume=3.0e-4 * n, gradient=5.0e-10 * n))
    else:
        parts += [_SUPPLY.format(s=i, displacement=1.2e-5, volume=3.0e-4, gradient=5.0e-10) for i in range(n)]
    parts += [_BOOM_CIRCUIT.format(i=i, s="" if layout == "shared" else i) for i in range(n)]
    (folder / "booms.circuit.toml").write_text("".join(parts))
    qpos = ", ".join(f"hinge{i} = 0.2003" for i in range(n))
    valves = "\n".join(f"valve{i} = {{ t = [0.0, 0.1, 0.2], value = [0.0, 0.0, 1.0] }}" for i in range(n))
    pumps = "\n".join(f"pump{s} = 40.0" for s in ([""] if layout == "shared" else range(n)))
    path = folder / "booms.scenario.toml"
    path.write_text(f'[scene]\nmjcf = "booms.xml"\ncircuit = "booms.circuit.toml"\n\n'
                    f'[run]\nmode = "mujoco"\ncoupling = "implicit"\ndt = {DT}\nduration = 10.0\n\n'
                    f'[initial]\nqpos = {{ {qpos} }}\nequilibrium = true\n\n[inputs]\n{valves}\n{pumps}\n')
    return path


def scenario_of(path: Path, mode: str):
    """The bench's run settings for ``mode`` on the scenario at ``path``."""
    scenario = load_scenario(path)
    if mode == "pbd":
        return scenario.with_overrides(mode="pbd", dt=DT, pbd_substeps=1)
    return scenario.with_overrides(mode="mujoco", dt=DT)


def time_run(scenario, steps: int) -> float:
    """Seconds per step of ``steps`` steps of a fresh plant of ``scenario`` in the runner's blocks."""
    plant = make_plant(load_scene(scenario))
    block = block_steps(scenario.dt)
    start = time.perf_counter()
    while plant.step_index < steps:
        report = plant.advance(min(block, steps - plant.step_index))
        if report is None or not report.success:
            raise RuntimeError(f"{scenario.path}: step {plant.step_index} failed")
    return (time.perf_counter() - start) / steps


def time_bare(scenario, steps: int) -> float:
    """Seconds per step of plain ``mj_step`` from the scenario's initial state with the MuJoCo plant's first effort
    law held as constant controls (``bench_fast.bare_start``)."""
    from bench_fast import bare_start

    plant = make_plant(load_scene(scenario))
    data = bare_start(plant)
    start = time.perf_counter()
    mujoco.mj_step(plant.model, data, nstep=steps)
    return (time.perf_counter() - start) / steps


def quartiles(values):
    """(lower quartile, median, upper quartile) of ``values``."""
    if len(values) < 2:
        return values[0], values[0], values[0]
    q = statistics.quantiles(values, n=4, method="inclusive")
    return q[0], statistics.median(values), q[2]


def exponent(t1, t2, n1, n2) -> float:
    return math.log(t2 / t1) / math.log(n2 / n1)


def measure(sizes, reps: int, window: float, modes=MODES, layouts=LAYOUTS):
    """{(mode, layout): {N: [seconds per step, one per round]}}, every size once per round in alternation."""
    steps = int(round(window / DT))
    times = {}
    with tempfile.TemporaryDirectory(prefix="hydroplant-scaling-") as tmp:
        scenarios = {}
        for layout in layouts:
            for n in sizes:
                folder = Path(tmp) / f"{layout}{n}"
                folder.mkdir()
                path = write_scene(folder, n, layout)
                for mode in modes:
                    scenarios[mode, layout, n] = scenario_of(path, mode)
        for key, scenario in scenarios.items():  # kernels loaded and the scene built once before the clock
            time_run(scenario, 2)
        for _ in range(reps):
            for (mode, layout, n), scenario in scenarios.items():
                times.setdefault((mode, layout), {}).setdefault(n, []).append(time_run(scenario, steps))
                if mode == "mujoco":
                    times.setdefault(("bare", layout), {}).setdefault(n, []).append(time_bare(scenario, steps))
    return times


def report(times, sizes, markdown: bool):
    """Prints the figures (and the Markdown tables of docs/benchmarks.md)."""
    for (mode, layout), by_size in times.items():
        cells = []
        for n in sizes:
            lo, med, hi = quartiles([t * 1e6 for t in by_size[n]])
            cells.append(f"N={n} {med:.1f} µs [{lo:.1f}, {hi:.1f}] ({med / n:.1f}/boom)")
        print(f"{mode:6s} {layout:6s} " + "  ".join(cells), flush=True)
    pairs = list(zip(sizes, sizes[1:]))
    if 4 in sizes and 32 in sizes:
        pairs.append((4, 32))
    lines = []
    for (mode, layout), by_size in times.items():
        cells = []
        for n1, n2 in pairs:
            lo, med, hi = quartiles([exponent(a, b, n1, n2) for a, b in zip(by_size[n1], by_size[n2])])
            cells.append(f"{med:.2f} [{lo:.2f}, {hi:.2f}]")
        lines.append((mode, layout, cells))
        print(f"exponent {mode:6s} {layout:6s} " + "  ".join(f"{a}→{b}: {c}" for (a, b), c in zip(pairs, cells)))
    if not markdown:
        return
    head = ["mode", "pumps", *[f"N = {n}" for n in sizes]]
    print("| " + " | ".join(head) + " |\n|" + "---|" * len(head))
    for (mode, layout), by_size in times.items():
        row = [LABELS.get(mode, mode), "one for all" if layout == "shared" else "one each"]
        row += [f"{statistics.median(by_size[n]) * 1e6:.0f} µs ({statistics.median(by_size[n]) * 1e6 / n:.1f}/boom)"
                for n in sizes]
        print("| " + " | ".join(row) + " |")
    print()
    head = ["mode", "pumps", *[f"{a} → {b}" for a, b in pairs]]
    print("| " + " | ".join(head) + " |\n|" + "---|" * len(head))
    for mode, layout, cells in lines:
        print("| " + " | ".join([LABELS.get(mode, mode), "one for all" if layout == "shared" else "one each", *cells]) + " |")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32], help="numbers of booms")
    parser.add_argument("--reps", type=int, default=5, help="rounds (each times every size once)")
    parser.add_argument("--window", type=float, default=0.3, help="simulated seconds per timed run")
    parser.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    parser.add_argument("--layouts", nargs="+", default=list(LAYOUTS), choices=LAYOUTS)
    parser.add_argument("--markdown", action="store_true", help="also print the tables of docs/benchmarks.md")
    args = parser.parse_args()
    if any(n < 1 for n in args.sizes) or args.reps < 1 or not args.window >= 10 * DT:
        parser.error("--sizes: whole numbers ≥ 1; --reps ≥ 1; --window ≥ 0.01 s")
    sizes = sorted(set(args.sizes))
    report(measure(sizes, args.reps, args.window, args.modes, args.layouts), sizes, args.markdown)


if __name__ == "__main__":
    main()
