"""End stops at the incompressible level: the dig cycle at frame rates stays within the strokes and joint ranges.

At the incompressible level a cylinder that could reach an end of its stroke within a step tracks a speed that ends
the step at that end (:func:`hydraulics._compiled_rigid.incompressible_law`), with at most the relief force, so
rigid oil holds the rod there.  In PBD mode that keeps the dig inside its strokes at 30 Hz (without it the bucket
cylinder went 3.1 mm past its curl end and the bucket joint 7.3 mrad past its range).  In MuJoCo mode the end cap
takes what pushes past the end (:func:`hydraulics._compiled_rigid.end_stop_hold`: the bound on that side dropped,
the tracker at full gain), and the trackers keep their force at the start speed strictly inside their bounds (MuJoCo
counts a force at its bound as clamped and drops the implicit term, which handed the light bucket the whole relief
force for a 33 ms step and threw it about); without both the bucket goes 416 mrad (30 Hz) and 147 mrad (60 Hz) past
its range and its cylinder 160 mm past its stroke.
"""

import mujoco
import pytest

from conftest import MODELS
from hydraulics.circuit import load_circuit
from sim.io.mcap_log import read_log
from sim.run.runner import run

DIG = MODELS / "excavator" / "dig.scenario.toml"
# The end-speed window keeps x + h·v⁺ inside the stroke in each PBD substep (h = dt/20); what is left is the
# tracker's residual, 1/(1 + G) of the speed change, and the stroke's curvature in the joint angle over one substep:
# measured 0.002 mm at 30 Hz and 0.001 mm at 60 Hz.  PBD's own joint limit leaves 0.034 mrad at both rates.
# MuJoCo mode holds the end with the tracker over the whole step (G = 100): measured 0.31 mm / 0.32 mrad at 30 Hz and
# 0.15 mm / 0.35 mrad at 60 Hz past the bucket's retracted end.
STROKE_TOLERANCE = {"pbd": 1e-4, "mujoco": 1e-3}  # m
JOINT_TOLERANCE = {"pbd": 5e-4, "mujoco": 1e-3}  # rad


@pytest.mark.parametrize("mode", ["pbd", "mujoco"])
@pytest.mark.parametrize("rate", [30, 60])
def test_incompressible_dig_stays_within_strokes_and_joint_ranges(mode, rate, tmp_path):
    """The dig-and-dump cycle (20 s) at 30 and 60 Hz completes with the plausibility monitor on, and every cylinder
    stays inside [0, stroke] and every joint inside its MJCF range within the tolerances above."""
    result = run(DIG, out=tmp_path / f"dig_{mode}_{rate}.mcap",
                 overrides={"fidelity": "incompressible", "dt": 1 / rate, "mode": mode})
    assert result.status == "complete", result.message
    log = read_log(result.log_path)
    circuit = load_circuit(MODELS / "excavator" / "excavator.circuit.toml")
    stroke_tolerance, joint_tolerance = STROKE_TOLERANCE[mode], JOINT_TOLERANCE[mode]
    for cylinder in circuit.by_kind("cylinder"):
        x = log.topic(f"/hydroplant/cylinders/{cylinder.name}")["position_m"]
        assert x.min() >= -stroke_tolerance, (cylinder.name, x.min())
        assert x.max() <= cylinder.params.stroke + stroke_tolerance, (cylinder.name, x.max())
    model = mujoco.MjModel.from_xml_path(str(MODELS / "excavator" / "excavator.xml"))
    joints = log.topic("/hydroplant/joint_states")
    for name in ("boom", "stick", "bucket"):
        low, high = model.joint(name).range
        q = joints[f"position/{name}"]
        assert low - joint_tolerance <= q.min() and q.max() <= high + joint_tolerance, (name, q.min(), q.max())
    # the stops are exercised, not just never approached: the bucket is opened to its stop at the dump in both modes,
    # and in PBD mode it also curls to its end (in MuJoCo mode the curl ends 0.12 m short of it)
    bucket = log.topic("/hydroplant/cylinders/bucket_cyl")["position_m"]
    stroke = circuit.component("bucket_cyl").params.stroke
    assert bucket.min() < 1e-3
    assert mode == "mujoco" or bucket.max() > stroke - 1e-3


def test_the_end_cap_holds_only_a_tracker_of_the_end_speed():
    """MuJoCo mode's end stop (hydraulics._compiled_rigid.end_stop_hold) on the bucket cylinder 1 mm from its curl
    end at 30 Hz: a tracker of the end speed v_hi = 1 mm / h gets the retracting side unbounded and the full gain
    G·m_eff/h, its extending bound kept; a tracker of a slower speed, a damper and the same tracker mid-stroke are
    returned unchanged (runs that never reach an end are not touched)."""
    import math

    import numpy as np

    from hydraulics import _compiled_rigid as K
    from sim.io.scenario import load_scenario
    from sim.io.scene import load_scene
    from sim.run.runner import make_plant

    plant = make_plant(load_scene(load_scenario(DIG).with_overrides(fidelity="incompressible", dt=1 / 30)), fast=False)
    F, I = plant.coupling.packed
    net, table = plant.network, plant.coupling.table
    a = list(net.actuator_names).index("bucket_cyl")
    stroke, h, mass = float(net.cylinder_stroke[list(net.cylinder_actuator).index(a)]), 1 / 30, 800.0
    n = net.actuator_count
    x, v, m = np.full(n, 0.5), np.zeros(n), np.full(n, mass)
    x[a], v[a] = stroke - 1e-3, 0.2
    lower, upper = np.full(n, -2e5), np.full(n, 4e5)
    gain = K.INCOMPRESSIBLE_TRACKING_GAIN * mass / h
    end_speed = 1e-3 / h

    def hold(target, slope=-1e4, position=x):
        const = np.zeros(n)
        const[a] = -slope * target
        law = (const, np.full(n, slope), lower, upper)
        return law, K.end_stop_hold_entry(F, I, table, position, v, m, h, *law)

    _, (c, k, lo, hi) = hold(end_speed)
    assert lo[a] == -math.inf and hi[a] == upper[a]
    assert k[a] == pytest.approx(-gain) and c[a] == pytest.approx(gain * end_speed)
    others = np.arange(n) != a  # far from their ends: unchanged
    assert np.all(lo[others] == lower[others]) and np.all(k[others] == -1e4)
    middle = x.copy()
    middle[a] = 0.5 * stroke
    for law, held in (hold(0.5 * end_speed), hold(end_speed, slope=0.0), hold(end_speed, position=middle)):
        for given, returned in zip(law, held):
            np.testing.assert_array_equal(returned, given)
