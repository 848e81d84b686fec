"""Cost of controllers in compiled blocks: each closed loop against the same machine replaying its commands open loop.

Per row, the closed loop runs once step by step and its commands of every step are kept; the open loop is the same
scenario without the controllers, those commands given back as piecewise-linear schedules with a knot at every
step (so both runs step the same physics: the largest difference of the actuator coordinates between them is
printed).  Both then advance in the runner's blocks (``sim.run.runner.block_steps``) from the scenario's start over
the window, ``--reps`` times in alternating pairs, in CPU time of the stepping thread; the figure is the median of the paired ratios closed/open
(and the spread of the ratios, min–max), with the medians of µs per step.

Rows:

* ``arm``: ``tests/scenes/outside_arm_servo.scenario.toml``, the outside arm whose lift valve command is 20 /m
  times the stroke error, every step (MuJoCo mode; and PBD mode at the scenario's PBD defaults);
* ``excavator``: ``models/excavator/dig.scenario.toml`` with its boom, stick and bucket valves driven by three
  PI controllers (every step) tracking the strokes of the open-loop dig, sampled every 0.1 s; swing and pump keep
  their schedules.

The Python controller ``controller(t, sensors)`` (``sim.plants.controllers.PythonController``) on the arm, every
step and at 100 Hz, is timed in the same pairs against the compiled PID at the same rate.

Run: ``.venv/bin/python bench/bench_control.py [--reps 5] [--window 6]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import time
from pathlib import Path

import numpy as np

from sim.io.scenario import PidSpec, Schedule, load_scenario
from sim.io.scene import load_scene
from sim.plants.controllers import PythonController
from sim.run.runner import block_steps, make_plant

ROOT = Path(__file__).resolve().parents[1]
ARM = ROOT / "tests" / "scenes" / "outside_arm_servo.scenario.toml"
DIG = ROOT / "models" / "excavator" / "dig.scenario.toml"


def excavator_closed(window: float):
    """The dig with PI controllers on the boom, stick and bucket valves tracking the open-loop dig's strokes."""
    scenario = load_scenario(DIG).with_overrides(duration=window)
    plant = make_plant(load_scene(scenario))
    names = ("boom", "stick", "bucket")
    index = [plant.network.actuator_names.index(f"{n}_cyl") for n in names]
    times, strokes = [0.0], [plant.net_state.actuator_position[index].copy()]
    while plant.step_index < scenario.step_count:
        plant.advance(100)
        times.append(plant.time)
        strokes.append(plant.net_state.actuator_position[index].copy())
    strokes = np.array(strokes)
    controllers = {f"{n}_stroke": PidSpec(output=f"{n}_valve", sensor=("stroke", f"{n}_cyl"),
                                          setpoint=Schedule(np.array(times), strokes[:, i]), kp=10.0, ki=5.0)
                   for i, n in enumerate(names)}
    inputs = {k: v for k, v in scenario.inputs.items() if k not in {f"{n}_valve" for n in names}}
    return dataclasses.replace(scenario, inputs=inputs, controllers=controllers)


def open_loop(closed):
    """``closed`` without its controllers, their outputs replayed from a step-by-step run as schedules."""
    plant = make_plant(load_scene(closed))
    outputs = [spec.output for spec in closed.controllers.values()]
    net = plant.network
    columns = []
    while plant.step_index < closed.step_count:
        plant.advance(1)
        control = plant.control
        columns.append([control.valve_command[net.valve_names.index(o)] if o in net.valve_names
                        else control.pump_speed[net.pump_names.index(o)] for o in outputs])
    columns = np.array(columns)
    t = np.arange(len(columns)) * closed.dt
    inputs = dict(closed.inputs)
    inputs.update({o: Schedule(t, columns[:, i]) for i, o in enumerate(outputs)})
    return dataclasses.replace(closed, controllers={}, inputs=inputs), plant.net_state.actuator_position.copy()


def timed(plant, steps, block):
    """CPU seconds of this thread advancing ``plant`` from its reset over ``steps`` in blocks of ``block`` (CPU time:
    on a shared machine the wall time also counts the other processes' time slices)."""
    plant.reset()
    start = time.thread_time()
    while plant.step_index < steps:
        plant.advance(min(block, steps - plant.step_index))
    return time.thread_time() - start


def kernel_ns(plant, calls=200_000):
    """ns per call of the controllers' compiled update (:func:`hydraulics.controllers.update`) at ``plant``'s state,
    in a compiled loop: what the closed loop adds to a step."""
    import numba

    from hydraulics import controllers as CT

    @numba.njit
    def loop(table, state, setpoint, dt, sources, cmd, speed, calls):
        for k in range(calls):
            CT.update(table, state, setpoint, k, dt, sources, cmd, speed)

    bank, net, control = plant.controllers, plant.net_state, plant.control
    sources = (net.actuator_position, net.actuator_velocity, plant.data.qpos.copy(), plant.data.qvel.copy(),
               net.node_pressure, np.zeros(len(plant.network.branch_names)))
    args = (bank.table, bank.state.copy(), bank.setpoint_rows(np.array([0.0]))[0], plant.dt, sources,
            control.valve_command.copy(), control.pump_speed.copy())
    loop(*args, 10)
    best = math.inf
    for _ in range(5):
        start = time.thread_time()
        loop(*args, calls)
        best = min(best, (time.thread_time() - start) / calls * 1e9)
    return best


def pairs(plants, steps, block, reps):
    """Alternating timings of the plants {label: plant}: per label the list of seconds."""
    times = {label: [] for label in plants}
    for label, plant in plants.items():  # warm: kernels loaded, caches filled
        timed(plant, min(steps, block), block)
    for _ in range(reps):
        for label, plant in plants.items():
            times[label].append(timed(plant, steps, block))
    return times


def row(label, times, steps, base="open", other="closed"):
    ratios = [c / o for c, o in zip(times[other], times[base])]
    med = {k: statistics.median(v) / steps * 1e6 for k, v in times.items()}
    return (f"| {label} | {med[base]:.2f} | {med[other]:.2f} | {statistics.median(ratios):.3f} | "
            f"{min(ratios):.3f}–{max(ratios):.3f} |")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=15)
    parser.add_argument("--window", type=float, default=2.0, help="simulated seconds per timed run")
    args = parser.parse_args()
    lines = ["| machine | open loop µs/step | closed loop µs/step | closed/open (median) | spread | controllers' kernel ns/step | share of the open-loop step |",
             "|---|---|---|---|---|---|---|"]
    checks = []
    cases = [("arm, MuJoCo mode", load_scenario(ARM).with_overrides(duration=args.window)),
             ("arm, PBD mode", load_scenario(ARM).with_overrides(duration=args.window, mode="pbd")),
             ("excavator, 3 PI, MuJoCo mode", excavator_closed(args.window))]
    for label, closed in cases:
        opened, end = open_loop(closed)
        plants = {"closed": make_plant(load_scene(closed)), "open": make_plant(load_scene(opened))}
        steps, block = closed.step_count, block_steps(closed.dt)
        times = pairs(plants, steps, block, args.reps)
        share = ""
        if closed.mode == "mujoco":
            ns = kernel_ns(plants["closed"])
            share = f" {ns:.0f} | {ns / (statistics.median(times['open']) / steps * 1e9) * 100:.2f} % |"
        lines.append(row(label, times, steps) + (share or " — | — |"))
        replay = plants["open"]
        replay.reset()
        replay.advance(steps)
        checks.append(f"{label}: open-loop replay ends within {np.max(np.abs(replay.net_state.actuator_position - end)):.2e} "
                      f"of the closed loop's actuator coordinates")
    # the Python callable against the compiled PID on the arm, every step and at 100 Hz
    lines += ["", "| arm, MuJoCo mode | compiled PID µs/step | Python controller(t, sensors) µs/step | Python/compiled | spread |",
              "|---|---|---|---|---|"]
    for rate in (None, 100.0):
        closed = load_scenario(ARM).with_overrides(duration=min(args.window, 2.0))
        spec = dataclasses.replace(closed.controllers["lift"], rate=rate)
        compiled = make_plant(load_scene(dataclasses.replace(closed, controllers={"lift": spec})))
        free = dataclasses.replace(closed, controllers={})
        python = make_plant(load_scene(free))
        kp, setpoint = spec.kp, spec.setpoint

        def law(t, sensors, kp=kp, setpoint=setpoint):
            return {"lift_valve": min(1.0, max(-1.0, kp * (setpoint(t) - sensors["stroke:lift_cyl"])))}

        python.python_controller = PythonController(python, law, sensors=["stroke:lift_cyl"], rate=rate)
        times = pairs({"compiled": compiled, "python": python}, closed.step_count, block_steps(closed.dt), args.reps)
        lines.append(row("every step" if rate is None else f"{rate:g} Hz", times, closed.step_count, "compiled", "python"))
    print("\n".join(lines))
    print()
    print("\n".join(checks))


if __name__ == "__main__":
    main()
