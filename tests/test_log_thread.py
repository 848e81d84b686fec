"""The log's writer thread: frame batches filled, encoded and written there give the file the caller's thread writes,
and the fields it computes agree with the state logged beside them."""

import functools
import threading

import numpy as np
import pytest

from conftest import MODELS, messages_by_topic
from sim.io.log_schemas import LogLevel, flat_schema, log_message
from sim.io.mcap_log import LogWriter, read_log
from sim.run.recorder import RunRecorder
from sim.run.runner import run
import sim.run.runner


def _frame_log(path, rows, *, deferred, chunk_thread, calls):
    """A frame of 4 columns (channel /a on columns 0-1 every row, /b on 2-3 at every 3rd step) and an event channel,
    its rows buffered in pieces by extend() or defer(); small batches and flushes split the deferred pieces."""
    schema = flat_schema("t_msgs/msg/Two", {"x": "x [1]", "y": "y [1]"})
    with LogWriter(path, dt=1e-3, batch_size=16, flush_interval=0.05, chunk_size=2000, chunk_thread=chunk_thread) as log:
        frame = log.frame(4)
        frame.channel("/a", schema, fields=["x", "y"], columns=[0, 1])
        frame.channel("/b", schema, fields=["x", "y"], columns=[2, 3], every=3)
        events = log.channel("/e", "foxglove.Log", {"type": "object"})
        for start in range(0, len(rows), 23):
            steps = np.arange(start, min(start + 23, len(rows)))
            if deferred:
                piece = rows[steps].copy()  # the caller hands this piece over

                def fill(out, lo, hi, piece=piece, first=start):
                    calls.append((first + lo, first + hi, threading.current_thread().name))
                    out[:] = piece[lo:hi]
                frame.defer(steps, fill)
            else:
                frame.extend(steps, rows[steps])
            events.write(int(steps[-1]), log_message(LogLevel.INFO, f"to step {steps[-1]}"))


def test_deferred_rows_give_the_extended_file_on_either_thread(tmp_path):
    """Frame.defer (rows filled when their batch is encoded) writes the file Frame.extend writes, byte for byte,
    on the writer thread and in the caller's; every row is filled exactly once, on the writer thread when it runs."""
    rows = np.random.default_rng(7).normal(size=(300, 4))
    calls = {name: [] for name in ("extend", "inline", "thread")}
    _frame_log(tmp_path / "extend.mcap", rows, deferred=False, chunk_thread=False, calls=calls["extend"])
    _frame_log(tmp_path / "inline.mcap", rows, deferred=True, chunk_thread=False, calls=calls["inline"])
    _frame_log(tmp_path / "thread.mcap", rows, deferred=True, chunk_thread=True, calls=calls["thread"])
    expected = (tmp_path / "extend.mcap").read_bytes()
    assert (tmp_path / "inline.mcap").read_bytes() == expected
    assert (tmp_path / "thread.mcap").read_bytes() == expected
    for name in ("inline", "thread"):
        filled = np.zeros(len(rows), dtype=int)
        for lo, hi, _ in calls[name]:
            filled[lo:hi] += 1
        assert (filled == 1).all(), name
    assert len(calls["thread"]) > len(rows) // 23  # pieces split at batch ends and flushes
    assert {t for _, _, t in calls["inline"]} == {threading.current_thread().name}
    assert all(t.startswith("mcap-chunks") for _, _, t in calls["thread"])
    log = read_log(tmp_path / "thread.mcap")
    np.testing.assert_array_equal(log.topic("/a")["x"], rows[:, 0])
    np.testing.assert_array_equal(log.topic("/b")["y"], rows[::3, 3])


@pytest.fixture(scope="module")
def dig_logs(tmp_path_factory):
    """The excavator dig's first 0.25 s logged every step, with the writer thread and without it."""
    folder = tmp_path_factory.mktemp("thread")
    overrides = {"duration": 0.25, "log_rate_hz": 1000.0}
    threads = []
    fill = RunRecorder._fill

    def spy(self, *args):
        threads.append(threading.current_thread().name)
        return fill(self, *args)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(RunRecorder, "_fill", spy)
        thread = run(MODELS / "excavator" / "dig.scenario.toml", out=folder / "thread.mcap", overrides=overrides)
        on_thread = list(threads)
        patch.setattr(sim.run.runner, "LogWriter", functools.partial(LogWriter, chunk_thread=False))
        inline = run(MODELS / "excavator" / "dig.scenario.toml", out=folder / "inline.mcap", overrides=overrides)
    assert thread.status == inline.status == "complete"
    return thread, inline, on_thread


def test_a_run_logs_the_same_messages_whichever_thread_derives_its_fields(dig_logs):
    """The recorder's fields computed on the writer thread (while the plant steps on) are the ones computed in the
    run's thread: every message, byte for byte."""
    thread, inline, on_thread = dig_logs
    assert on_thread and all(name.startswith("mcap-chunks") for name in on_thread)
    assert messages_by_topic(thread.log_path) == messages_by_topic(inline.log_path)
    assert thread.energy == inline.energy and thread.final_strokes == inline.final_strokes


def test_fields_derived_on_the_writer_thread_agree_with_the_logged_state(dig_logs):
    """Each cylinder's pressure force and oil stiffness, and the energy residual, recomputed from the pressures,
    positions and energy terms the log holds beside them, by the network's own relations: equal to the last bit."""
    from sim.io.scene import load_scene

    thread = dig_logs[0]
    net = load_scene(thread.scenario).network
    log = read_log(thread.log_path)
    nodes = log.topic("/hydroplant/nodes")
    p = np.column_stack([nodes[name] for name in nodes.fields if name.startswith("pressure_pa.")])
    x = np.zeros((len(p), net.actuator_count))
    for a in net.cylinder_actuator:
        x[:, a] = log.topic(f"/hydroplant/cylinders/{net.actuator_names[a]}")["position_m"]
    for a in net.motor_actuator:
        x[:, a] = log.topic(f"/hydroplant/motors/{net.actuator_names[a]}")["angle_rad"]
    force = net.pressure_effort(p)
    stiffness = net.chamber_stiffness(p, x, net.node_volume_at(x, p)).sum(axis=1)
    for i, a in enumerate(net.cylinder_actuator):
        cylinder = log.topic(f"/hydroplant/cylinders/{net.actuator_names[a]}")
        assert len(cylinder) == 251  # steps 0 to 250
        np.testing.assert_array_equal(cylinder["pressure_force_n"], force[:, a])
        np.testing.assert_array_equal(cylinder["stiffness_npm"], stiffness[:, i])
        np.testing.assert_array_equal(cylinder["p_cap_bar"], cylinder["p_cap_pa"] / 1e5)
    energy = log.topic("/hydroplant/energy")
    stored = energy["kinetic_j"] + energy["potential_j"] + energy["oil_j"]
    dissipated = energy["dissipated_hydraulic_j"] + energy["dissipated_friction_j"] + energy["dissipated_mechanical_j"]
    residual = energy["pump_work_j"] - (stored - (stored[0] + energy["residual_j"][0] - energy["pump_work_j"][0]
                                                  + dissipated[0])) - dissipated
    np.testing.assert_allclose(energy["residual_j"], residual, rtol=0, atol=1e-9 * np.abs(stored).max())
