"""End stops at the incompressible level: the dig cycle at frame rates stays within the strokes and joint ranges.

At the incompressible level a cylinder that could reach an end of its stroke within a step tracks a speed that ends
the step at that end (:func:`hydraulics._compiled_rigid.incompressible_law`), with at most the relief force, so
rigid oil holds the rod there.  In PBD mode that keeps the dig inside its strokes at 30 Hz (without it the bucket
cylinder went 3.1 mm past its curl end and the bucket joint 7.3 mrad past its range).  In MuJoCo mode the curled
bucket is pushed past its end by the ground with more than the 200 kN the rod side holds at the relief setting
(the cylinder's law sits at that bound while the rod moves on), so there the runs still leave the ranges: those
cases are expected failures until the stop can take more than the relief force in MuJoCo's step.
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
# measured 0.002 mm at 30 Hz and 0.001 mm at 60 Hz.
STROKE_TOLERANCE = 1e-4  # m
# PBD's own joint limit leaves 0.034 mrad at both rates (with and without the stop).
JOINT_TOLERANCE = 5e-4  # rad
MUJOCO_PAST = pytest.mark.xfail(strict=True, reason="the ground pushes the curled bucket past its end with more than "
                                                    "the relief force (see the module docstring)")


@pytest.mark.parametrize("mode", ["pbd", pytest.param("mujoco", marks=MUJOCO_PAST)])
@pytest.mark.parametrize("rate", [30, 60])
def test_incompressible_dig_stays_within_strokes_and_joint_ranges(mode, rate, tmp_path):
    """The dig-and-dump cycle (20 s) at 30 and 60 Hz completes with the plausibility monitor on, and every cylinder
    stays inside [0, stroke] and every joint inside its MJCF range within the tolerances above."""
    result = run(DIG, out=tmp_path / f"dig_{mode}_{rate}.mcap",
                 overrides={"fidelity": "incompressible", "dt": 1 / rate, "mode": mode})
    assert result.status == "complete", result.message
    log = read_log(result.log_path)
    circuit = load_circuit(MODELS / "excavator" / "excavator.circuit.toml")
    for cylinder in circuit.by_kind("cylinder"):
        x = log.topic(f"/hydroplant/cylinders/{cylinder.name}")["position_m"]
        assert x.min() >= -STROKE_TOLERANCE, (cylinder.name, x.min())
        assert x.max() <= cylinder.params.stroke + STROKE_TOLERANCE, (cylinder.name, x.max())
    model = mujoco.MjModel.from_xml_path(str(MODELS / "excavator" / "excavator.xml"))
    joints = log.topic("/hydroplant/joint_states")
    for name in ("boom", "stick", "bucket"):
        low, high = model.joint(name).range
        q = joints[f"position/{name}"]
        assert low - JOINT_TOLERANCE <= q.min() and q.max() <= high + JOINT_TOLERANCE, (name, q.min(), q.max())
    # the bucket reaches both ends in this cycle (curl, dump): the stops are exercised, not just never approached
    bucket = log.topic("/hydroplant/cylinders/bucket_cyl")["position_m"]
    stroke = circuit.component("bucket_cyl").params.stroke
    assert bucket.max() > stroke - 1e-3 and bucket.min() < 1e-3
