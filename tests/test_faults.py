"""Faults and logs of ``hydroplant run``: divergence, Ctrl-C, SIGKILL + recover, and ``log info``.

* A diverging run stops at the step where it diverged, names the simulation
  time and the component, and its log holds every logged step up to it,
  marked ``diverged``.
* SIGINT (Ctrl-C) to a running ``hydroplant run`` leaves a finished, indexed
  MCAP with everything so far, marked ``incomplete`` (exit status 130).
* SIGKILL leaves ``<out>.partial``; ``hydroplant log recover`` rebuilds a valid
  MCAP from its complete chunks, equal to the start of an uninterrupted run.
* ``hydroplant log info`` prints scene, mode, duration, topics, counts and the
  completeness of each kind of log.

(Determinism of two runs is tested in test_run_logs.py.)
"""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from mcap.reader import make_reader

from conftest import MODELS, ROOT
from sim.cli import main
from sim.io.mcap_log import read_log
from sim.run.runner import run

LIFT = MODELS / "boom" / "lift.scenario.toml"
SEED = MODELS / "seed_cylinder" / "closed.scenario.toml"
SIGNAL_DT = "5e-3"  # s: a coarse but stable implicit step so the subprocess reaches its first flush (2 s) quickly
STARTUP_TIMEOUT = 60.0  # s of wall time for the subprocess to start logging
MAIN_TOPICS = ("/hydroplant/joint_states", "/hydroplant/cylinders/boom_cyl", "/hydroplant/nodes", "/hydroplant/energy")


def _default_sigint():
    """SIGINT at its default in the child: a suite started in the background by a non-interactive shell
    inherits it ignored, and Python then installs no KeyboardInterrupt handler."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start_run(out, *extra):
    """``python -m sim.cli run LIFT ...`` in a subprocess (the console script's entry point)."""
    return subprocess.Popen(
        [sys.executable, "-m", "sim.cli", "run", str(LIFT), "--dt", SIGNAL_DT, "--duration", "36000", "--no-progress",
         "--out", str(out), *extra],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env={**os.environ, "PYTHONUNBUFFERED": "1"},
        preexec_fn=_default_sigint,
    )


def wait_for_chunk(partial, process):
    """Wait until the .partial file holds at least one complete chunk of messages (a snapshot of it recovers some)."""
    from sim.io.mcap_log import recover

    deadline = time.monotonic() + STARTUP_TIMEOUT
    snapshot = partial.with_name("snapshot.mcap.partial")
    while time.monotonic() < deadline:
        assert process.poll() is None, process.communicate()
        if partial.exists():
            snapshot.write_bytes(partial.read_bytes())
            try:
                if recover(snapshot, snapshot.with_name("snapshot.mcap"), overwrite=True).message_count > 0:
                    return
            except ValueError:  # not even the magic yet
                pass
        time.sleep(0.1)
    process.kill()
    pytest.fail(f"{partial} held no complete chunk within {STARTUP_TIMEOUT} s")


def assert_prefix_of_clean_run(log, tmp_path, name):
    """Every topic's messages equal the first messages of an uninterrupted run of the same scenario."""
    end = log.end_time_ns / 1e9
    clean = read_log(run(LIFT, out=tmp_path / f"{name}-clean.mcap", overrides={"dt": float(SIGNAL_DT), "duration": end + 0.05}).log_path)
    for topic in log.topics:
        got = log.topic(topic)
        want = clean.topic(topic)
        assert len(got) <= len(want), topic
        assert np.array_equal(got.log_time, want.log_time[: len(got)]), topic
        assert got.messages == want.messages[: len(got)], topic


def assert_indexed(path):
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.chunk_indexes and summary.statistics.message_count > 0


# ------------------------------------------------------------------------------------ divergence
def test_diverging_run_stops_with_time_and_component(tmp_path):
    """Explicit coupling at 30 Hz on the boom lift: the supply node's forward-Euler step blows up (the plausibility
    monitor, which would stop the run when the supply passes its 441 bar bound, is off)."""
    result = run(LIFT, out=tmp_path / "diverged.mcap",
                 overrides={"coupling": "explicit", "dt": 1 / 30, "duration": 2.0, "monitor": False})
    assert result.status == "diverged"
    assert result.message.startswith(f"t = {result.simulated_time:.6g} s, node supply: ")
    assert 0 < result.simulated_time < 2.0
    log = read_log(result.log_path)
    assert log.status == "diverged"
    meta = log.metadata["hydroplant.result"]
    assert meta["component"] == "node supply" and float(meta["time_s"]) == pytest.approx(result.simulated_time)
    # every step up to the failure is logged (30 Hz steps, 100 Hz log rate: one sample per step), the last one is the failure
    for topic in MAIN_TOPICS:
        t = log.topic(topic).log_time
        assert len(t) == result.steps + 1, topic
        assert np.array_equal(t, np.round(np.arange(result.steps + 1) * 1e9 / 30).astype(np.int64)), topic
    events = log.topic("/hydroplant/events")
    assert any("diverged" in m["message"] and "node supply" in m["message"] for m in events.messages)
    assert events.log_time[-1] == log.end_time_ns


def test_energy_growth_divergence_names_the_coupling(tmp_path, capsys):
    """The undamped seed cylinder with explicit coupling: energy growth, exit status 3 from the CLI."""
    out = tmp_path / "seed.mcap"
    assert main(["run", str(SEED), "--coupling", "explicit", "--out", str(out), "--no-progress"]) == 3
    printed = capsys.readouterr().out
    assert "status        diverged: t = " in printed and "energy growth" in printed
    log = read_log(out)
    assert log.status == "diverged" and log.metadata["hydroplant.result"]["component"] == "coupling (energy growth)"
    t = log.topic("/hydroplant/energy").log_time
    assert float(log.metadata["hydroplant.result"]["time_s"]) == pytest.approx(t[-1] / 1e9)


# ------------------------------------------------------------------------------------ signals
def test_ctrl_c_leaves_a_finished_incomplete_log(tmp_path):
    out = tmp_path / "interrupted.mcap"
    process = start_run(out)
    wait_for_chunk(out.with_name(out.name + ".partial"), process)
    time.sleep(0.3)
    process.send_signal(signal.SIGINT)
    stdout, stderr = process.communicate(timeout=60)
    assert process.returncode == 130, stderr.decode()
    assert b"Traceback" not in stderr and b"interrupted" in stderr
    assert out.exists() and not out.with_name(out.name + ".partial").exists()
    assert_indexed(out)
    log = read_log(out)
    assert log.status == "incomplete" and log.metadata["hydroplant.result"]["reason"] == "interrupted"
    assert log.end_time_ns > 1e9  # past the first flush: everything up to the interrupt
    assert_prefix_of_clean_run(log, tmp_path, "ctrl-c")
    # no hole: the 100 Hz samples are contiguous from t = 0 to the end
    t = log.topic("/hydroplant/joint_states").log_time
    assert t[0] == 0 and np.all(np.diff(t) == 10_000_000) and t[-1] == log.end_time_ns


def test_sigkill_leaves_a_partial_file_that_recovers(tmp_path, capsys):
    out = tmp_path / "killed.mcap"
    partial = out.with_name(out.name + ".partial")
    process = start_run(out)
    wait_for_chunk(partial, process)
    process.send_signal(signal.SIGKILL)
    process.communicate(timeout=60)
    assert process.returncode == -signal.SIGKILL
    assert partial.exists() and not out.exists()
    assert main(["log", "info", str(partial)]) == 0
    assert "UNFINISHED" in capsys.readouterr().out
    recovered = tmp_path / "recovered.mcap"
    assert main(["log", "recover", str(partial), str(recovered)]) in (0, 1)  # 1 when the cut chunk was skipped
    printed = capsys.readouterr().out
    assert f"recovered log: {recovered}" in printed
    assert_indexed(recovered)
    log = read_log(recovered)
    assert log.status == "recovered"
    assert set(MAIN_TOPICS) <= set(log.topics) and all(log.message_counts[t] > 0 for t in MAIN_TOPICS)
    assert set(log.attachments) == {"scenario.toml", "circuit.toml", "boom.xml"}
    assert log.metadata["hydroplant.run"]["scene"] == "boom"
    assert_prefix_of_clean_run(log, tmp_path, "sigkill")
    # the default output name when none is given
    assert main(["log", "recover", str(partial)]) in (0, 1)
    assert (tmp_path / "killed.recovered.mcap").is_file()


# ------------------------------------------------------------------------------------ log info
@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """One finished log of each status: complete, diverged, incomplete (exception in the loop) and recovered."""
    d = tmp_path_factory.mktemp("info")
    complete = run(LIFT, out=d / "complete.mcap", overrides={"dt": 5e-3, "duration": 0.5}).log_path
    diverged = run(LIFT, out=d / "diverged.mcap", overrides={"coupling": "explicit", "dt": 1 / 30, "duration": 2.0}).log_path
    partial = d / "cut.mcap.partial"
    data = complete.read_bytes()
    partial.write_bytes(data[: len(data) * 2 // 3])
    recovered = d / "recovered.mcap"
    assert main(["log", "recover", str(partial), str(recovered)]) == 1  # the record cut in two is skipped
    return {"complete": complete, "diverged": diverged, "recovered": recovered}


@pytest.mark.parametrize("kind, status", [("complete", "status: complete"), ("diverged", "status: diverged (time_s="),
                                          ("recovered", "status: recovered (")])
def test_log_info_prints_scene_mode_duration_topics_counts_completeness(logs, kind, status, capsys):
    capsys.readouterr()
    assert main(["log", "info", str(logs[kind])]) == 0
    text = capsys.readouterr().out
    assert status in text
    assert "scene: boom" in text and "mode: mujoco" in text and "duration_s: " in text
    assert "topics:" in text and "/hydroplant/cylinders/boom_cyl" in text
    log = read_log(logs[kind])
    line = next(l for l in text.splitlines() if l.strip().startswith("/hydroplant/nodes"))
    assert int(line.split()[1]) == log.message_counts["/hydroplant/nodes"] > 0
    assert "logged: 0 s .. " in text


def test_log_info_of_an_incomplete_log(tmp_path, capsys):
    """An exception inside the loop (here: a plant that raises) finishes the log as incomplete with the reason."""
    from sim.run import runner

    class Boom(RuntimeError):
        pass

    original = runner.make_plant

    def failing_plant(scene, **options):
        plant = original(scene, **options)
        step = plant.step
        advance = getattr(plant, "advance", None)

        def step_then_fail():
            if plant.step_index >= 20:
                failed_at.append(plant.step_index)
                raise Boom("injected fault")
            return step()

        def advance_then_fail(n):  # the runner's block path (MujocoPlantFast): the first block call from step 20 on
            if plant.step_index >= 20:
                failed_at.append(plant.step_index)
                raise Boom("injected fault")
            return advance(n)

        plant.step = step_then_fail
        if advance is not None:
            plant.advance = advance_then_fail
        return plant

    failed_at = []
    runner.make_plant = failing_plant
    try:
        with pytest.raises(Boom):
            run(LIFT, out=tmp_path / "broken.mcap", overrides={"dt": 5e-3, "duration": 3.0})
    finally:
        runner.make_plant = original
    assert main(["log", "info", str(tmp_path / "broken.mcap")]) == 0
    text = capsys.readouterr().out
    assert "status: incomplete" in text and "Boom: injected fault" in text and "scene: boom" in text
    log = read_log(tmp_path / "broken.mcap")
    # samples every 2 steps, each one simulated before the fault (step 20, or the end of the block that passed it)
    assert len(failed_at) == 1 and failed_at[0] >= 20
    assert log.topic("/hydroplant/joint_states").log_time[-1] == (failed_at[0] // 2) * 2 * 5_000_000


@pytest.mark.parametrize("fast", [False, True])
def test_a_mujoco_reset_is_a_divergence_not_a_fresh_start(fast):
    """MuJoCo resets the bodies to the reference pose when qvel is huge (> mjMAXVAL = 1e10) and only counts a
    warning; the plant reports that step as non-finite instead of stepping on from the reset pose."""
    from sim.plants.mujoco import MujocoPlant
    from sim.plants.mujoco_fast import MujocoPlantFast
    from sim.io.scenario import load_scenario
    from sim.io.scene import load_scene

    scene = load_scene(load_scenario(MODELS / "boom" / "hold.scenario.toml"))
    plant = MujocoPlantFast(scene) if fast else MujocoPlant(scene)
    assert (plant.advance(10) if fast else plant.step()).success
    plant.data.qvel[0] = 1e12
    report = plant.advance(10) if fast else plant.step()
    assert not report.success and "MuJoCo reset the bodies" in report.message
