"""Operator inputs for the two plants whose coupled step is one compiled call per block of steps.

:class:`sim.plants.mujoco_fast.MujocoPlantFast` (n MuJoCo steps per ``mj_step``)
and :class:`sim.plants.pbd.PbdPlant`'s compiled frame (all XPBD substeps of a
step) sample the scenario's input schedules for every (sub)step of the block
beforehand, into rows of valve-command and pump-speed buffers, as
:func:`hydraulics.load.apply_inputs` would set them one step at a time.
Plain Python and numpy: nothing here is compiled into a kernel (so no source
fingerprint needs it).
"""

from __future__ import annotations

import numpy as np

from sim.io.scenario import Schedule


def input_plan(network, control, inputs):
    """Per scenario input (``inputs``: name → schedule): (is_valve, index, schedule) for :func:`sample_inputs`.

    A pump is any law component with a scheduled input (``network.pump_names``: the fixed, compensated and
    load-sensing pumps' shaft speeds).  A name that is neither a valve nor a pump of ``network`` raises the usual
    :class:`KeyError` of ``network.set_control`` (on ``control``).
    """
    plan = []
    for name, schedule in inputs.items():
        if name in network.valve_names:
            plan.append((True, network.valve_names.index(name), schedule))
        elif name in network.pump_names:
            plan.append((False, network.pump_names.index(name), schedule))
        else:
            network.set_control(control, name, 0.0)  # raises the usual KeyError
    return plan


def sample_inputs(plan, times, cmd, speed):
    """Rows of ``cmd`` (valve commands [-]) and ``speed`` (pump speeds [rev/s]) at ``times`` [s], one row per time:
    piecewise-linear schedules vectorised, schedules with a ``sample(times)`` method (the operator commands of
    :mod:`sim.run.commands`) asked once, other callables called per time, constants broadcast.  Columns of inputs
    without a schedule are left as they are."""
    for is_valve, index, schedule in plan:
        target = cmd if is_valve else speed
        if isinstance(schedule, Schedule):
            target[:, index] = np.interp(times, schedule.t, schedule.value)
        elif callable(getattr(schedule, "sample", None)):  # vectorised (sim.run.commands.HeldInput)
            target[:, index] = schedule.sample(times)
        elif callable(schedule):
            target[:, index] = [schedule(t) for t in times]
        else:
            target[:, index] = schedule
