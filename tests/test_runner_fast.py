"""The runner's block path (MujocoPlantFast, one ``mj_step(nstep=n)`` per log sample) against its per-step path.

* Both paths log the same values to round-off on the boom lift and the seed
  cylinder (every float field of every topic, relative to the field's range).
* A block whose hydraulic step fails is rewound and replayed step by step: the
  run stops at the same step, with the same time and component, and logs the
  same samples, marked ``diverged``, as the per-step path.
* Peak and minimum pressures: per-step extremes when the plant keeps them,
  otherwise bounded by the per-step path's and by the logged samples.
"""

import math

import numpy as np
import pytest

from conftest import MODELS
from hydraulics._compiled import compiled_available
from sim.io.mcap_log import read_log
from sim.run.runner import run
from sim.io.scenario import load_scenario

pytestmark = pytest.mark.skipif(not compiled_available(), reason="numba is not installed")

LIFT = MODELS / "boom" / "lift.scenario.toml"
SEED = MODELS / "seed_cylinder" / "closed.scenario.toml"
VALUE_RTOL = 1e-9  # of each field's largest magnitude over the run (round-off of different summation orders)
VALUE_ATOL = 1e-12  # SI units: floor for fields that stay near zero (a holding boom's speed is ~1e-8 rad/s)
# The Newton solver's final residual is noise at the level of its tolerance, not a physical value:
# compared as "both tiny" instead of to round-off.
NOISE_FIELDS = {("/hydroplant/solver", "residual_pa")}
RESIDUAL_PA = 1.0  # Pa


def assert_logs_agree(path_a, path_b, *, drop_last=False):
    """Same topics, times and values; ``drop_last`` skips the values of each topic's last message (a failed step's
    state: the per-step path logs what the failed step left, NaN included; the block path the last good network)."""
    a, b = read_log(path_a), read_log(path_b)
    assert set(a.topics) == set(b.topics)
    compared = 0
    for topic in a.topics:
        ta, tb = a.topic(topic), b.topic(topic)
        assert np.array_equal(ta.log_time, tb.log_time), topic
        if not hasattr(ta, "fields"):
            continue
        assert ta.fields == tb.fields, topic
        for name in ta.fields:
            x, y = np.asarray(ta[name]), np.asarray(tb[name])
            if drop_last:
                x, y = x[:-1], y[:-1]
            if x.dtype.kind != "f" or not len(x):
                assert np.array_equal(x, y), (topic, name)
                continue
            if (topic, name) in NOISE_FIELDS:
                assert np.nanmax(np.abs(x)) < RESIDUAL_PA and np.nanmax(np.abs(y)) < RESIDUAL_PA
                continue
            scale = np.nanmax(np.abs(y)) if np.any(np.isfinite(y)) else 0.0
            if (topic, name) == ("/hydroplant/energy", "residual_j"):  # a balance of the other terms: their round-off
                scale = max(np.nanmax(np.abs(tb[f])) for f in tb.fields if f.endswith("_j"))
            np.testing.assert_allclose(x, y, rtol=0, atol=VALUE_RTOL * scale + VALUE_ATOL, err_msg=f"{topic} {name}")
            compared += 1
    assert compared > 30
    return a, b


@pytest.mark.parametrize("path, overrides", [
    (LIFT, {"duration": 1.6, "dt": 2e-3}),  # holds, then the valve opens over 1.0-1.3 s and the boom lifts
    (SEED, {"duration": 0.05}),             # the seed's closed cylinder at 1200 Hz, logged every step
])
def test_block_and_per_step_paths_log_the_same_values(tmp_path, path, overrides):
    fast = run(path, out=tmp_path / "blocks.mcap", overrides=overrides)
    slow = run(path, out=tmp_path / "steps.mcap", overrides=overrides, fast=False)
    assert fast.status == slow.status == "complete"
    assert fast.steps == slow.steps == load_scenario(path).with_overrides(**overrides).step_count
    a, b = assert_logs_agree(fast.log_path, slow.log_path)
    assert a.metadata["hydroplant.run"]["stepping"] == "blocks"
    assert b.metadata["hydroplant.run"]["stepping"] == "per-step"
    for key in ("pump_work", "dissipated", "delta"):
        assert fast.energy[key] == pytest.approx(slow.energy[key], rel=1e-9, abs=1e-9)
    for joint, q in slow.final_joints.items():
        assert fast.final_joints[joint] == pytest.approx(q, rel=0, abs=1e-9)


def test_pressure_extremes_of_the_block_path(tmp_path):
    """Boom lift: the supply and cap pressures jump while the valve opens (1.0-1.3 s)."""
    overrides = {"duration": 1.6, "dt": 2e-3}
    fast = run(LIFT, out=tmp_path / "blocks.mcap", overrides=overrides)
    slow = run(LIFT, out=tmp_path / "steps.mcap", overrides=overrides, fast=False)
    from sim.plants.mujoco_fast import MujocoPlantFast  # noqa: F401  (attribute names below)
    from sim.run.runner import _PLANT_EXTREMES
    from sim.io.scene import load_scene

    per_step = all(hasattr(MujocoPlantFast(load_scene(load_scenario(LIFT))), name) for name in _PLANT_EXTREMES)
    assert slow.extremes_every_step and fast.extremes_every_step == per_step
    nodes = read_log(fast.log_path).topic("/hydroplant/nodes")
    for node, peak in slow.peak_pressure.items():
        logged = nodes[f"pressure_pa.{node}"]
        if per_step:  # over every step, like the per-step path
            assert fast.peak_pressure[node] == pytest.approx(peak, rel=1e-9)
            assert fast.min_pressure[node] == pytest.approx(slow.min_pressure[node], rel=1e-9)
        else:  # over the block ends = the logged samples
            assert fast.peak_pressure[node] == pytest.approx(np.max(logged), rel=1e-12)
            assert fast.min_pressure[node] == pytest.approx(np.min(logged), rel=1e-12)
            assert fast.peak_pressure[node] <= peak * (1 + 1e-9)
            assert fast.min_pressure[node] >= slow.min_pressure[node] * (1 - 1e-9)


@pytest.mark.parametrize("rate_hz", [100.0, 500.0])
def test_failed_block_is_replayed_to_the_failing_step(tmp_path, rate_hz):
    """A valve command that turns NaN at t = 0.2371 s fails the hydraulic step of t = 0.238 s mid-block
    (5-step blocks at 2 ms and a 100 Hz log; 1-step blocks at 500 Hz): both paths stop at step 120 and log the same
    samples up to it."""
    scenario = load_scenario(LIFT).with_overrides(duration=0.5, dt=2e-3, log_rate_hz=rate_hz)
    base = scenario.inputs["boom_valve"]

    def command(t):
        return math.nan if t >= 0.2371 else float(np.interp(t, base.t, base.value))

    scenario = scenario.with_overrides(inputs={**scenario.inputs, "boom_valve": command})
    fast = run(scenario, out=tmp_path / "blocks.mcap")
    slow = run(scenario, out=tmp_path / "steps.mcap", fast=False)
    assert fast.status == slow.status == "diverged"
    assert fast.steps == slow.steps == 120 and fast.simulated_time == slow.simulated_time
    assert fast.message.split(":")[0] == slow.message.split(":")[0] == "t = 0.24 s, node supply"
    a, b = assert_logs_agree(fast.log_path, slow.log_path, drop_last=True)
    for log in (a, b):
        assert log.status == "diverged"
        assert log.metadata["hydroplant.result"]["time_s"] == repr(0.24)
        t = log.topic("/hydroplant/nodes").log_time
        if rate_hz == 100.0:  # samples every 10 ms up to 0.23 s, then the failing step
            assert np.array_equal(t, np.append(np.arange(24) * 10_000_000, 240_000_000))
        else:  # every step up to the failing one
            assert np.array_equal(t, np.arange(121) * 2_000_000)
        assert any("diverged" in m["message"] for m in log.topic("/hydroplant/events").messages)


@pytest.mark.parametrize("path, overrides", [
    (SEED, {"duration": 0.05}),                                           # every step (1200 Hz), one 60-step block
    (LIFT, {"duration": 2.2, "dt": 2e-3, "log_rate_hz": 250.0}),          # every 2nd step, across a periodic flush
    (LIFT, {"duration": 1.1, "dt": 1e-3}),                                # the default 100 Hz: every 10th step
])
def test_samples_recorded_inside_blocks_give_the_same_log_file(tmp_path, monkeypatch, path, overrides):
    """The plant records the samples inside each block from its compiled loop (MujocoPlantFast.advance(n, record,
    every); blocks run one step past their last sample, or hold several samples when the log interval is shorter than
    runner.block_steps(dt)): the log file is byte for byte the one written with one block per sample, each captured by the
    recorder from Python, and so is the summary."""
    from sim.run import runner

    original = runner._Loop.block_end
    lengths = []

    def logged_block_end(self, k):
        end = original(self, k)
        lengths.append(end - k)
        return end

    monkeypatch.setattr(runner._Loop, "block_end", logged_block_end)
    recorded = run(path, out=tmp_path / "recorded.mcap", overrides=overrides)
    scenario = load_scenario(path).with_overrides(**overrides)
    every = scenario.log_every
    # blocks with samples recorded inside, as long as the run allows
    assert max(lengths) > every and max(lengths) >= min(runner.block_steps(scenario.dt), scenario.step_count)
    calls = []

    def one_sample_per_block(self, k):
        self.record_blocks = False
        end = original(self, k)
        calls.append(end - k)
        return end

    monkeypatch.setattr(runner._Loop, "block_end", one_sample_per_block)
    captured = run(path, out=tmp_path / "captured.mcap", overrides=overrides)
    assert max(calls) == min(calls[:-1]) == every  # one log interval per block
    assert recorded.status == captured.status == "complete" and recorded.steps == captured.steps
    assert (tmp_path / "recorded.mcap").read_bytes() == (tmp_path / "captured.mcap").read_bytes()
    assert recorded.energy == captured.energy and recorded.final_joints == captured.final_joints
    assert recorded.peak_pressure == captured.peak_pressure and recorded.min_pressure == captured.min_pressure


def test_replay_from_an_older_snapshot_gives_the_same_log(tmp_path, monkeypatch):
    """A failed block is replayed from the last snapshot (taken every SNAPSHOT_STEPS steps): the steps from the
    snapshot to the block's start are advanced again, unlogged.  The diverged run's log file and summary are byte
    for byte those of a snapshot at every block start (the same arithmetic either way)."""
    from sim.run import runner

    scenario = load_scenario(LIFT).with_overrides(duration=0.5, dt=2e-3, log_rate_hz=500.0)
    base = scenario.inputs["boom_valve"]

    def command(t):  # fails the hydraulic step of t = 0.238 s (step 120), inside a 10-step block
        return math.nan if t >= 0.2371 else float(np.interp(t, base.t, base.value))

    scenario = scenario.with_overrides(inputs={**scenario.inputs, "boom_valve": command})
    assert runner.SNAPSHOT_STEPS > 20
    older = run(scenario, out=tmp_path / "older.mcap")
    monkeypatch.setattr(runner, "SNAPSHOT_STEPS", 1)
    every_block = run(scenario, out=tmp_path / "every_block.mcap")
    assert older.status == every_block.status == "diverged" and older.steps == every_block.steps == 120
    assert older.message == every_block.message
    assert (tmp_path / "older.mcap").read_bytes() == (tmp_path / "every_block.mcap").read_bytes()
    assert repr((older.energy, older.final_joints)) == repr((every_block.energy, every_block.final_joints))  # NaNs


def test_blocks_span_the_flush_interval_or_a_hundred_steps():
    """The block path's block length: the log's flush interval (2 s) of simulated time at fine steps, never fewer than
    MIN_BLOCK_STEPS steps; the recorder's ring holds a block's samples logged every step at 1 kHz."""
    from sim.io.log_writer import DEFAULT_FLUSH_INTERVAL
    from sim.run import recorder, runner

    assert runner.BLOCK_SECONDS == DEFAULT_FLUSH_INTERVAL == 2.0
    assert runner.block_steps(1e-3) == 2000 == recorder.RING_SIZE
    assert runner.block_steps(1 / 1200) == 2400
    assert runner.block_steps(1 / 60) == 120
    assert runner.block_steps(0.1) == runner.MIN_BLOCK_STEPS == 100
    assert runner.block_steps(1e-5) == 200_000
