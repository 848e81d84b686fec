"""Data safety: nothing a user has is overwritten or read unsafely, signals leave a finished log, caches are verified.

Every command run by these tests is checked not to change what the user wrote: the scene's
files (scenario, circuit, MJCF, includes, assets) and the shipped models are hashed before and
after it (:func:`hydroplant`, :func:`user_files`).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import MODELS, ROOT
from hydraulics.components import CircuitError
from hydraulics.files import MAX_INPUT_BYTES, read_text
from sim import cli
from sim.io.files import check_output, free_path
from sim.io.mcap_log import read_log

SCENARIO = "hold.scenario.toml"
SHORT = ("--duration", "0.01", "--no-progress")


@pytest.fixture
def scene(tmp_path):
    """A copy of the boom scene whose MJCF takes its <visual> from an include outside the scene's folder."""
    folder = tmp_path / "boom"
    shutil.copytree(MODELS / "boom", folder)
    shared = tmp_path / "common"
    shared.mkdir()
    (shared / "visual.xml").write_text('<mujoco><visual><global offwidth="640" offheight="480"/></visual></mujoco>\n')
    mjcf = folder / "boom.xml"
    text = mjcf.read_text()
    start, end = text.index("  <visual>"), text.index("</visual>") + len("</visual>")
    mjcf.write_text(text[:start] + '  <include file="../common/visual.xml"/>' + text[end:])
    return folder


def user_files(folder: Path) -> dict:
    """SHA-256 of every file the user wrote (the scene folder and the shared include)."""
    files = sorted(p for p in [*folder.iterdir(), *(folder.parent / "common").glob("*")] if p.is_file() and p.suffix != ".mcap"
                   and not p.name.endswith(".partial"))
    return {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in files}


def watched_files(argv) -> dict:
    """SHA-256 of what a command must not change: the shipped models and the folders of the files it names
    (with the scene fixture's shared folder), logs excepted."""
    folders = {MODELS}
    for arg in argv:
        path = Path(arg) if isinstance(arg, Path) else None
        if path is not None and path.is_file() and path.suffix != ".mcap":
            folders |= {path.parent, path.parent.parent / "common"}
    files = sorted(p for folder in folders if folder.is_dir() for p in folder.rglob("*")
                   if p.is_file() and p.suffix != ".mcap" and not p.name.endswith(".partial") and "__pycache__" not in p.parts)
    return {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in files}


def hydroplant(*argv, capsys):
    """(exit code, stdout, stderr lines) of an in-process ``hydroplant ARGV``; the user's files must not change."""
    before = watched_files(argv)
    try:
        code = cli.main([str(a) for a in argv])
    except SystemExit as exc:
        code = exc.code
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    assert watched_files(argv) == before
    return code, out, [line for line in err.splitlines() if line.strip()]


def refused(scene, capsys, *argv, expected: str):
    """Run ``hydroplant run SCENARIO ARGV``: exit 2, one stderr line holding ``expected``, the user's files unchanged."""
    before = user_files(scene)
    code, _, err = hydroplant("run", scene / SCENARIO, *SHORT, *argv, capsys=capsys)
    assert code == 2 and len(err) == 1, (code, err)
    assert expected in err[0], err
    assert user_files(scene) == before
    return err[0]


# ------------------------------------------------------------------------------------ --out
@pytest.mark.parametrize("name", ["hold.scenario.toml", "boom.circuit.toml", "boom.xml", "../common/visual.xml"])
def test_out_never_replaces_an_input_of_the_run(scene, capsys, name):
    line = refused(scene, capsys, "--out", scene / name, "--overwrite", expected="is an input of this run")
    assert Path(name).name in line


def test_out_at_a_device_is_refused_and_the_device_stays_one(scene, capsys):
    refused(scene, capsys, "--out", "/dev/null", "--overwrite", expected="/dev/null: is a character device, not a regular file")
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)


def test_out_at_a_folder_is_refused_without_a_stray_partial(scene, capsys, tmp_path):
    folder = tmp_path / "logs"
    folder.mkdir()
    refused(scene, capsys, "--out", folder, "--overwrite", expected="is a directory, not a regular file")
    assert folder.is_dir() and not (tmp_path / "logs.partial").exists()


def test_out_empty_nul_and_too_long_names_are_refused(scene, capsys, tmp_path):
    refused(scene, capsys, "--out", "", expected="an empty file name")
    refused(scene, capsys, "--out", str(tmp_path / "a") + "\0b", expected="NUL byte")
    refused(scene, capsys, "--out", tmp_path / ("x" * 250 + ".mcap"), expected="file name too long")
    with pytest.raises(CircuitError, match="not a folder"):
        check_output(scene / SCENARIO / "run.mcap")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_out_in_a_read_only_folder_is_refused(scene, capsys, tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        refused(scene, capsys, "--out", folder / "run.mcap", expected="is not writable")
    finally:
        folder.chmod(0o700)


def test_out_at_an_existing_log_needs_overwrite(scene, capsys, tmp_path):
    out = tmp_path / "run.mcap"
    before = user_files(scene)
    assert hydroplant("run", scene / SCENARIO, *SHORT, "--out", out, capsys=capsys)[0] == 0
    first = out.read_bytes()
    refused(scene, capsys, "--out", out, expected=f"{out}: exists; pass --overwrite")
    assert out.read_bytes() == first
    code, _, err = hydroplant("run", scene / SCENARIO, *SHORT, "--out", out, "--overwrite", "--dt", "5e-4", capsys=capsys)
    assert code == 0 and not err
    assert read_log(out).metadata["hydroplant.run"]["dt_s"] == "0.0005"  # replaced by the new run
    assert user_files(scene) == before


def test_out_with_an_existing_partial_is_refused_and_the_partial_kept(scene, capsys, tmp_path):
    out = tmp_path / "run.mcap"
    partial = tmp_path / "run.mcap.partial"
    partial.write_bytes(b"\x89MCAP0\r\n" + b"left by a killed run" * 1000)
    kept = partial.read_bytes()
    line = refused(scene, capsys, "--out", out, expected=f"{partial}: exists")
    assert f"hydroplant log recover {partial}" in line
    assert partial.read_bytes() == kept and not out.exists()


def test_default_log_names_never_name_an_existing_file(tmp_path):
    taken = tmp_path / "boom-hold-mujoco-implicit-T.mcap"
    taken.write_bytes(b"a user's log")
    (tmp_path / "boom-hold-mujoco-implicit-T-2.mcap.partial").write_bytes(b"a killed run's data")
    assert free_path(taken) == tmp_path / "boom-hold-mujoco-implicit-T-3.mcap"
    assert free_path(tmp_path / "new.mcap") == tmp_path / "new.mcap"


def test_run_defaults_to_refusing_an_existing_out(scene, tmp_path):
    from sim.run.runner import run

    out = tmp_path / "run.mcap"
    out.write_bytes(b"the user's data")
    with pytest.raises(CircuitError, match="exists"):
        run(scene / SCENARIO, out=out, overrides={"duration": 0.01})
    assert out.read_bytes() == b"the user's data"


# ---------------------------------------------------------------------- subprocess commands
def start(*argv, cwd):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen([sys.executable, "-m", "sim.cli", *map(str, argv)], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_two_runs_on_one_out_one_is_refused_the_other_log_is_valid(scene, tmp_path):
    out = tmp_path / "shared.mcap"
    before = user_files(scene)
    runs = [start("run", scene / SCENARIO, "--duration", "2", "--no-progress", "--out", out, cwd=tmp_path) for _ in range(2)]
    results = [(p.wait(timeout=120), *p.communicate()) for p in runs]
    codes = sorted(code for code, _, _ in results)
    assert codes == [0, 2], results
    _, _, err = next(r for r in results if r[0] == 2)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and str(out) in lines[0] and "Traceback" not in err, err
    log = read_log(out)
    assert log.metadata["hydroplant.result"]["status"] == "complete"
    assert not (tmp_path / "shared.mcap.partial").exists()
    assert user_files(scene) == before


@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGHUP, 129)])
def test_sigterm_and_sighup_mid_run_finish_the_log_marked_incomplete(scene, tmp_path, sig, code):
    out = tmp_path / "long.mcap"
    before = user_files(scene)
    proc = start("run", scene / SCENARIO, "--duration", "1000", "--no-progress", "--out", out, cwd=tmp_path)
    partial = tmp_path / "long.mcap.partial"
    deadline = time.monotonic() + 120
    # mid-run: chunks of samples written (the header and the attached inputs are ~22 kB, a second of samples ~1 MB)
    while (not partial.exists() or partial.stat().st_size < 100_000) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.01)
    assert proc.poll() is None, proc.communicate()  # still running: the signal lands mid-run
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and f"interrupted ({signal.Signals(sig).name})" in lines[0] and str(out) in lines[0], err
    result = read_log(out).metadata["hydroplant.result"]
    assert result["status"] == "incomplete" and result["reason"] == "interrupted"
    assert 0 < float(result["end_time_s"]) < 1000
    assert not partial.exists() and user_files(scene) == before


def test_a_stop_request_ends_a_run_as_ctrl_c_does(scene, tmp_path):
    """``run(stop=...)`` (what ``hydroplant run`` passes, so that an interrupt a library swallowed still counts):
    asked before the log is opened (no log then) and before every block (the log finished, marked interrupted)."""
    from sim.run.runner import RunInterrupted, run

    with pytest.raises(KeyboardInterrupt):
        run(scene / SCENARIO, out=tmp_path / "early.mcap", overrides={"duration": 1.0}, stop=lambda: True)
    assert not list(tmp_path.glob("early.mcap*"))
    asked = []

    def later():
        asked.append(1)
        return len(asked) > 5  # before the log, then before each of the first blocks

    with pytest.raises(RunInterrupted):
        run(scene / SCENARIO, out=tmp_path / "late.mcap", overrides={"duration": 100.0}, stop=later)
    result = read_log(tmp_path / "late.mcap").metadata["hydroplant.result"]
    assert result["status"] == "incomplete" and result["reason"] == "interrupted"
    assert 0 < float(result["end_time_s"]) < 100.0 and not list(tmp_path.glob("*.partial"))


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_during_start_up_exits_quietly(scene, tmp_path, sig, code):
    proc = start("run", scene / SCENARIO, "--duration", "0.01", "--no-progress", "--out", tmp_path / "x.mcap", cwd=tmp_path)
    # During start-up: once MuJoCo's library is mapped (the command's imports), long before the scene is loaded and
    # the plant's kernels are read, the child is frozen, signalled and let go, whatever the machine's load.
    maps = Path(f"/proc/{proc.pid}/maps")
    deadline = time.monotonic() + 60
    while "libmujoco" not in maps.read_text() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.002)
    proc.send_signal(signal.SIGSTOP)
    assert not list(tmp_path.glob("x.mcap*"))  # no log opened yet: still starting up
    proc.send_signal(sig)
    proc.send_signal(signal.SIGCONT)
    out, err = proc.communicate(timeout=60)
    # MuJoCo is loaded by the command's imports, after main() has installed its handlers: 128 + signal
    assert proc.returncode == code and err == "", (proc.returncode, err)
    assert not list(tmp_path.glob("x.mcap*"))


# ------------------------------------------------------------------------------------ inputs
def test_a_fifo_as_scenario_is_refused_at_once(tmp_path):
    fifo = tmp_path / "pipe.scenario.toml"
    os.mkfifo(fifo)
    started = time.monotonic()
    proc = start("run", fifo, "--no-progress", cwd=tmp_path)
    _, err = proc.communicate(timeout=30)
    assert time.monotonic() - started < 5.0
    assert proc.returncode == 2 and err.strip() == f"hydroplant: error: {fifo}: scenario file is a FIFO (named pipe), not a regular file"


@pytest.mark.parametrize("which", ["circuit", "csv", "include"])
def test_a_fifo_among_the_inputs_is_refused_without_blocking(scene, capsys, which):
    target = {"circuit": scene / "boom.circuit.toml", "csv": scene / "inputs.csv", "include": scene.parent / "common" / "visual.xml"}[which]
    if which == "csv":
        scenario = scene / SCENARIO
        scenario.write_text('inputs_csv = "inputs.csv"\n' + scenario.read_text())
    else:
        target.unlink()
    os.mkfifo(target)
    code, _, err = hydroplant("run", scene / SCENARIO, *SHORT, "--out", scene.parent / "x.mcap", capsys=capsys)
    assert code == 2 and len(err) == 1 and f"{target}" in err[0] and "FIFO" in err[0], err


def test_devices_loops_nul_bytes_huge_and_non_utf8_files_are_one_line(scene, capsys, tmp_path):
    loop = tmp_path / "loop.toml"
    loop.symlink_to(tmp_path / "loop2.toml")
    (tmp_path / "loop2.toml").symlink_to(loop)
    big = tmp_path / "big.scenario.toml"
    with open(big, "wb") as f:
        f.truncate(MAX_INPUT_BYTES + 1)  # sparse: no disk used
    nul = tmp_path / "nul.scenario.toml"
    nul.write_bytes((scene / SCENARIO).read_bytes().replace(b"[run]", b"[run]\0"))
    latin = tmp_path / "latin.scenario.toml"
    latin.write_bytes((scene / SCENARIO).read_bytes() + b"# \xe9t\xe9\n")
    for path, expected in [("/dev/zero", "/dev/zero: scenario file is a character device, not a regular file"),
                           (loop, f"{loop}: scenario file: symbolic link loop"),
                           (big, f"{big}: scenario file is {MAX_INPUT_BYTES + 1} B; at most {MAX_INPUT_BYTES} B (64 MiB)"),
                           (nul, f"{nul}: scenario file holds a NUL byte at byte"),
                           (latin, f"{latin}: scenario file is not UTF-8 text")]:
        code, _, err = hydroplant("run", path, *SHORT, capsys=capsys)
        assert code == 2 and len(err) == 1 and expected in err[0], (path, err)
    with pytest.raises(CircuitError, match="NUL byte"):
        read_text("a\0b", "scenario")


def test_mjcf_includes_outside_the_scene_are_attached_to_the_log(scene, capsys, tmp_path):
    out = tmp_path / "run.mcap"
    code, stdout, err = hydroplant("run", scene / SCENARIO, *SHORT, "--out", out, capsys=capsys)
    assert code == 0 and not err
    log = read_log(out)
    assert log.attachments["../common/visual.xml"] == (scene.parent / "common" / "visual.xml").read_bytes()
    assert log.attachments["boom.xml"] == (scene / "boom.xml").read_bytes()
    assert list(log.attachments)[-1] == "boom.xml"  # the MJCF itself last (compare's scene identity)
    assert set(log.attachments) == {"scenario.toml", "circuit.toml", "../common/visual.xml", "boom.xml"}


@pytest.mark.parametrize("value", ["nan", "inf"])
def test_nan_or_inf_mass_in_the_mjcf_is_one_line(scene, capsys, value):
    mjcf = scene / "boom.xml"
    mjcf.write_text(mjcf.read_text().replace('mass="150"', f'mass="{value}"'))
    refused(scene, capsys, "--out", scene.parent / "x.mcap", expected="body 'boom', <inertial> mass")


@pytest.mark.parametrize("argv, expected", [
    (("--dt", "5e-324"), "field 'run.dt': 5e-324 is not in [1e-09, 1] s"),
    (("--dt", "2"), "field 'run.dt': 2.0 is not in [1e-09, 1] s"),
    (("--dt", "1e-3", "--duration", "5e-4"), "field 'run.duration': 0.0005 s is shorter than one step (dt = 0.001 s)"),
])
def test_step_sizes_and_durations_out_of_range(scene, capsys, argv, expected):
    before = user_files(scene)
    code, _, err = hydroplant("run", scene / SCENARIO, "--no-progress", "--out", scene.parent / "x.mcap", *argv, capsys=capsys)
    assert code == 2 and len(err) == 1 and expected in err[0], err
    assert user_files(scene) == before


@pytest.mark.parametrize("old, new, expected", [
    ("[log]\nrate_hz = 100", "[log]\nrate_hz = 5e-324", "field 'rate_hz': 5e-324 is not a number in [1e-06, 1000000000.0]"),
    ("[log]\nrate_hz = 100", "[log]\nrate_hz = 1e300", "field 'rate_hz': 1e+300 is not a number in [1e-06, 1000000000.0]"),
    ("dt = 0.001 ", "dt = 5e-324 ", "field 'dt': 5e-324 is not a number in [1e-09, 1.0]"),
    ("value = [0.0] }   # spool", "value = [5.0] }   # spool",
     "field 'inputs.boom_valve': value 5.0 at t = 0.0 s is outside the valve command range [-1, 1] of 'boom_valve'"),
    ("value = [0.0] }   # spool", "value = [1e300] }   # spool", "outside the valve command range [-1, 1]"),
    ("value = [0.0] }   # spool", "value = [true] }   # spool", "'value' must be an array of numbers (not true/false"),
    ("value = [40.0] }", "value = [-40.0] }",
     "field 'inputs.pump': value -40.0 at t = 0.0 s is outside the pump speed range [0, 1000] rev/s of 'pump'"),
    ("value = [40.0] }", "value = [1e6] }", "outside the pump speed range [0, 1000] rev/s"),
    ("value = [40.0] }", "value = [nan] }", "NaN or inf in the schedule"),
])
def test_scenario_values_out_of_range(scene, capsys, old, new, expected):
    scenario = scene / SCENARIO
    text = scenario.read_text()
    assert text.count(old) == 1
    scenario.write_text(text.replace(old, new))
    line = refused(scene, capsys, "--out", scene.parent / "x.mcap", expected=expected)
    assert str(scenario) in line


# ------------------------------------------------------------------------------------ caches
def square(point):
    marker = Path(point["markers"]) / f"{point['x']}-{time.perf_counter_ns()}"
    marker.touch()
    if point.get("fail"):
        return {"status": "error", "message": "a failure the function caught"}
    return {"y": point["x"] ** 2}


def test_a_planted_sweep_cache_entry_is_rejected_and_recomputed(tmp_path):
    from sim.tools.sweep import point_key, run_sweep

    markers, cache = tmp_path / "markers", tmp_path / "cache"
    markers.mkdir()
    point = {"x": 3, "markers": str(markers)}
    cache.mkdir()
    planted = cache / f"{point_key(point, square)}.json"
    planted.write_text(json.dumps({"point": point, "result": {"y": 1000}}))  # the old layout, right key
    assert run_sweep(square, [point], workers=1, cache_dir=cache) == [{"y": 9}]
    assert len(list(markers.iterdir())) == 1
    entry = json.loads(planted.read_text())
    entry["result"] = {"y": 1000}  # a forged result without a matching digest
    planted.write_text(json.dumps(entry))
    assert run_sweep(square, [point], workers=1, cache_dir=cache) == [{"y": 9}]
    assert len(list(markers.iterdir())) == 2
    assert run_sweep(square, [point], workers=1, cache_dir=cache) == [{"y": 9}]  # a genuine entry is used
    assert len(list(markers.iterdir())) == 2
    assert run_sweep(square, [point], workers=1, cache_dir=cache, fresh=True) == [{"y": 9}]  # --fresh
    assert len(list(markers.iterdir())) == 3


def test_failed_sweep_points_are_not_cached(tmp_path):
    from sim.tools.sweep import run_sweep

    markers, cache = tmp_path / "markers", tmp_path / "cache"
    markers.mkdir()
    point = {"x": 1, "markers": str(markers), "fail": True}
    for n in (1, 2):
        assert run_sweep(square, [point], workers=1, cache_dir=cache)[0]["status"] == "error"
        assert len(list(markers.iterdir())) == n
    assert not list(cache.glob("*.json"))


def test_a_planted_reference_is_rejected_and_recomputed(tmp_path):
    from sim.io.scenario import load_scenario
    from sim.tools.reference import Tolerance, compute_reference

    scenario = load_scenario(MODELS / "seed_cylinder" / "closed.scenario.toml").with_overrides(duration=0.01)
    tol, cache = Tolerance(relative=0.02), tmp_path / "cache"
    first = compute_reference(scenario, tolerance=tol, cache_dir=cache, start_dt=1 / 4800)
    info_path = first.log_path.parent / "reference.json"
    info = json.loads(info_path.read_text())
    info["dt"] = 1.0  # a planted value
    info_path.write_text(json.dumps(info))
    again = compute_reference(scenario, tolerance=tol, cache_dir=cache, start_dt=1 / 4800)
    assert not again.cached and again.dt == first.dt
    assert compute_reference(scenario, tolerance=tol, cache_dir=cache, start_dt=1 / 4800).cached


def test_tradeoff_at_a_closed_scheduler_port_is_one_line(capsys):
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # closed once the socket is
    code, _, err = hydroplant("tradeoff", MODELS / "seed_cylinder" / "closed.scenario.toml", "--scheduler",
                              f"tcp://127.0.0.1:{port}", "--quick", capsys=capsys)
    assert code == 2 and len(err) == 1 and f"--scheduler tcp://127.0.0.1:{port}: no Dask scheduler reachable" in err[0]


def test_fresh_flags_exist_on_tradeoff_and_compare():
    parser = cli.build_parser()
    assert parser.parse_args(["tradeoff", "x.toml", "--fresh"]).fresh
    assert parser.parse_args(["compare", "x.toml", "--fresh"]).fresh


def test_a_full_disk_during_the_run_is_one_line_naming_the_log(scene, capsys, tmp_path, monkeypatch):
    import errno

    import sim.run.runner as runner

    def full(log, *args):
        log.path.with_name(log.path.name + ".partial").stat()  # the writer's file exists
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(runner, "_run_loop", full)
    out = tmp_path / "full.mcap"
    refused(scene, capsys, "--out", out, expected=f"{out}: cannot write the log (No space left on device); "
            "the log written so far is finished and marked incomplete")
    assert read_log(out).metadata["hydroplant.result"]["status"] == "incomplete"


def test_cache_keys_cover_the_mjcf_includes(scene):
    from sim.io.scenario import load_scenario
    from sim.io.scene import input_paths
    from sim.tools.reference import ReferenceSettings, reference_key
    from sim.tools.tradeoff import sweep_points

    scenario = load_scenario(scene / SCENARIO)
    include = scene.parent / "common" / "visual.xml"
    assert include in input_paths(scenario)
    key, files = reference_key(scenario, ReferenceSettings()), sweep_points(scenario, [{}], repeats=1)[0]["bundle"]
    include.write_text(include.read_text().replace('offwidth="640"', 'offwidth="800"'))
    assert reference_key(scenario, ReferenceSettings()) != key
    assert sweep_points(scenario, [{}], repeats=1)[0]["bundle"] != files


def tetrahedron_stl() -> bytes:
    """A binary STL of a 0.1 m tetrahedron (4 facets)."""
    import struct

    v = [(0, 0, 0), (0.1, 0, 0), (0, 0.1, 0), (0, 0, 0.1)]
    faces = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
    data = b"\0" * 80 + struct.pack("<I", len(faces))
    for face in faces:
        data += struct.pack("<3f", 0, 0, 0) + b"".join(struct.pack("<3f", *v[i]) for i in face) + b"\0\0"
    return data


def test_mesh_assets_are_read_safely_and_attached(scene, capsys, tmp_path):
    mesh = scene.parent / "common" / "tet.stl"
    mesh.write_bytes(tetrahedron_stl())
    mjcf = scene / "boom.xml"
    text = mjcf.read_text().replace("  <worldbody>", '  <asset><mesh name="tet" file="../common/tet.stl"/></asset>\n  <worldbody>', 1)
    mjcf.write_text(text.replace('<body name="boom" pos="0 0 1.5">', '<body name="boom" pos="0 0 1.5">\n'
                                 '      <geom type="mesh" mesh="tet" mass="0" contype="0" conaffinity="0"/>', 1))
    out = tmp_path / "mesh.mcap"
    code, _, err = hydroplant("run", scene / SCENARIO, *SHORT, "--out", out, capsys=capsys)
    assert code == 0 and not err, err
    assert read_log(out).attachments["../common/tet.stl"] == mesh.read_bytes()
    mesh.unlink()
    os.mkfifo(mesh)  # a FIFO as the mesh: refused before MuJoCo opens it
    code, _, err = hydroplant("run", scene / SCENARIO, *SHORT, "--out", tmp_path / "fifo.mcap", capsys=capsys)
    assert code == 2 and len(err) == 1 and f"{mesh}: MJCF asset <mesh file>" in err[0] and "FIFO" in err[0], err


def test_runs_at_one_instant_take_distinct_default_names(scene, tmp_path, monkeypatch):
    import datetime as dt
    from dataclasses import replace

    import sim.run.runner as runner
    from sim.io.scenario import load_scenario

    class Frozen(dt.datetime):
        @classmethod
        def now(cls, tz=None):
            return dt.datetime(2026, 1, 2, 3, 4, 5, 678901, tzinfo=tz)

    monkeypatch.setattr(runner._dt, "datetime", Frozen)
    scenario = replace(load_scenario(scene / SCENARIO), log_dir=tmp_path / "logs")
    first = runner.run(scenario, overrides={"duration": 0.01}).log_path
    second = runner.run(scenario, overrides={"duration": 0.01}).log_path
    stem = "boom-hold-mujoco-rosenbrock-20260102T030405678901Z"
    assert (first.name, second.name) == (f"{stem}.mcap", f"{stem}-2.mcap")
    assert read_log(first).metadata["hydroplant.result"]["status"] == "complete"


# ------------------------------------------------------------------------- tool output folders
def two_logs(folder: Path) -> tuple[Path, Path]:
    """Two small synthetic hydroplant logs (a reference and a run 1 mm off) in ``folder``."""
    from test_compare import sine, write_log

    folder.mkdir(parents=True, exist_ok=True)
    return (write_log(folder / "ref.mcap", 1e-3, 0.1, stroke=sine),
            write_log(folder / "run.mcap", 2e-3, 0.1, stroke=lambda t: sine(t) + 0.001))


@pytest.mark.parametrize("name", ["report.md", "overlay.png", "error.png", "merged.mcap"])
def test_compare_never_writes_through_a_link_in_its_folder(tmp_path, capsys, name):
    ref, run = two_logs(tmp_path / "logs")
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "notes.txt"
    victim.write_text("the user's notes\n")
    (out / name).symlink_to(victim)
    code, _, err = hydroplant("compare", ref, run, "--out", out, capsys=capsys)
    assert code == 2 and len(err) == 1 and f"{out / name}" in err[0] and "symbolic link" in err[0], err
    assert victim.read_text() == "the user's notes\n" and (out / name).is_symlink()


def test_tradeoff_never_writes_through_a_link_in_its_folder(tmp_path, capsys, monkeypatch):
    """Refused before the reference is computed; and its writers themselves never follow a link."""
    import sim.tools.reference
    from sim.tools.tradeoff import write_csv

    def not_reached(*args, **kwargs):
        raise AssertionError("the output folder is checked before any run")

    monkeypatch.setattr(sim.tools.reference, "compute_reference", not_reached)
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "table.csv"
    victim.write_text("the user's table\n")
    (out / "tradeoff.csv").symlink_to(victim)
    code, _, err = hydroplant("tradeoff", MODELS / "seed_cylinder" / "closed.scenario.toml", "--out", out, capsys=capsys)
    assert code == 2 and len(err) == 1 and f"{out / 'tradeoff.csv'}" in err[0] and "symbolic link" in err[0], err
    with pytest.raises(CircuitError, match="symbolic link"):
        write_csv([], out / "tradeoff.csv")
    assert victim.read_text() == "the user's table\n"


def test_compare_never_replaces_its_own_input(tmp_path, capsys):
    ref, run = two_logs(tmp_path / "logs")
    out = tmp_path / "out"
    out.mkdir()
    merged = out / "merged.mcap"  # a log the user keeps where compare writes its merged log
    shutil.copyfile(ref, merged)
    kept = merged.read_bytes()
    code, _, err = hydroplant("compare", merged, run, "--out", out, capsys=capsys)
    assert code == 2 and len(err) == 1 and f"{merged}" in err[0] and "is an input" in err[0], err
    assert merged.read_bytes() == kept and not (out / "report.md").exists()


def foreign_log(path: Path, payloads: list[bytes]) -> Path:
    """A valid, finished MCAP file written by another program: a JSON topic of hydroplant's name, no hydroplant records."""
    from mcap.writer import Writer

    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start(profile="", library="another-recorder")
        schema = writer.register_schema("Reading", "jsonschema", b'{"type": "object"}')
        channel = writer.register_channel("/hydroplant/cylinders/c", "json", schema)
        for n, data in enumerate(payloads):
            writer.add_message(channel, n * 10**8, data, n * 10**8)
        writer.finish()
    return path


@pytest.mark.parametrize("payload", [b'{"position_m": 0.5, "p_cap_pa": 1e7}', b"[1, 2]", b'{"position_m": "x"}',
                                     b"\xff\xfe not json"])
@pytest.mark.parametrize("foreign_first", [True, False])
def test_compare_on_a_foreign_log_is_one_line(tmp_path, capsys, foreign_first, payload):
    ref, _ = two_logs(tmp_path / "logs")
    other = foreign_log(tmp_path / "logs" / "camera.mcap", [payload] * 5)
    logs = (other, ref) if foreign_first else (ref, other)
    code, _, err = hydroplant("compare", *logs, "--out", tmp_path / "out", capsys=capsys)
    assert code == 2 and len(err) == 1 and f"{other}: not a hydroplant log" in err[0], err
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------------------- log recover
def _xxh32(data: bytes) -> int:
    """XXH32 with seed 0 (the LZ4 frame header checksum), for crafting a frame header."""
    p1, p2, p3, p4, p5, mask = 2654435761, 2246822519, 3266489917, 668265263, 374761393, 0xFFFFFFFF

    def rotl(x, r):
        return ((x << r) | (x >> (32 - r))) & mask

    n, i = len(data), 0
    h = (p5 + n) & mask  # frame descriptors are < 16 bytes: no stripe loop
    assert n < 16
    while i + 4 <= n:
        h = (rotl((h + int.from_bytes(data[i:i + 4], "little") * p3) & mask, 17) * p4) & mask
        i += 4
    while i < n:
        h = (rotl((h + data[i] * p5) & mask, 11) * p1) & mask
        i += 1
    h ^= h >> 15
    h = (h * p2) & mask
    h ^= h >> 13
    h = (h * p3) & mask
    return h ^ (h >> 16)


def crafted_chunk_log(path: Path, compression: str, claimed: int) -> Path:
    """A cut MCAP file (header, one chunk, no footer) whose chunk's compressed frame claims ``claimed`` bytes."""
    import struct
    import zlib

    message = struct.pack("<HIQQ", 1, 0, 0, 0) + bytes(100_000)
    inner = struct.pack("<BQ", 0x05, len(message)) + message
    if compression == "lz4":
        import lz4.frame

        frame = bytearray(lz4.frame.compress(inner, store_size=True))
        struct.pack_into("<Q", frame, 6, claimed)  # FLG, BD, then the 8-byte content size
        frame[14] = (_xxh32(bytes(frame[4:14])) >> 8) & 0xFF
        size = len(inner)  # the chunk's own field honest: only the frame lies
    else:
        import zstandard

        frame = bytearray(zstandard.ZstdCompressor(write_checksum=False).compress(inner))
        assert frame[4] >> 6 == 2 and frame[4] & 0x20  # a single-segment frame with a 4-byte content size
        struct.pack_into("<I", frame, 5, claimed)
        size = claimed
    name = compression.encode()
    body = (struct.pack("<QQQI", 0, 0, size, 0) + struct.pack("<I", len(name)) + name
            + struct.pack("<Q", len(frame)) + bytes(frame))
    header = struct.pack("<I", 0) + struct.pack("<I", 7) + b"crafted"
    data = (b"\x89MCAP0\r\n" + struct.pack("<BQ", 0x01, len(header)) + header
            + struct.pack("<BQ", 0x06, len(body)) + body)
    assert zlib.crc32(data) and len(data) < 70_000
    path.write_bytes(data)
    return path


@pytest.mark.parametrize("compression, claimed", [("lz4", 4_500_000_000), ("zstd", 0x7FFF0000)])
def test_a_crafted_chunk_length_allocates_nothing_big(tmp_path, capsys, compression, claimed):
    """A chunk whose frame claims gigabytes is damage, found without allocating what it claims."""
    import tracemalloc

    crafted = crafted_chunk_log(tmp_path / "crafted.mcap", compression, claimed)
    tracemalloc.start()
    try:
        info = hydroplant("log", "info", crafted, capsys=capsys)
        recovered = hydroplant("log", "recover", crafted, tmp_path / "out.mcap", capsys=capsys)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 64 * 2**20, f"{peak / 2**20:.0f} MiB allocated for a {crafted.stat().st_size} B file"
    assert info[0] == 1 and "DAMAGED" in info[1], info
    assert recovered[0] == 1 and "skipped: 1 damaged chunk" in recovered[1], recovered
    assert read_log(tmp_path / "out.mcap").metadata["hydroplant.result"]["status"] == "recovered"


# ------------------------------------------------------------------------------ start-up signal
@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGHUP, 129)])
def test_a_signal_while_the_command_loads_its_modules_exits_128_plus_signal(tmp_path, sig, code):
    """The signal is sent by the child itself when the command imports the hydraulics package (the
    slow part of start-up): deterministic, whatever the machine's load."""
    script = (
        "import os, runpy, signal, sys\n"
        "class SignalOnImport:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'hydraulics.components':\n"
        f"            os.kill(os.getpid(), {int(sig)})\n"
        "        return None\n"
        "sys.meta_path.insert(0, SignalOnImport())\n"
        "sys.argv = ['hydroplant', 'examples']\n"
        "runpy.run_module('sim.cli', run_name='__main__')\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == code and proc.stderr == "" and proc.stdout == "", (proc.returncode, proc.stderr)


# ------------------------------------------------------------------------------ --no-progress
def test_no_progress_hides_the_progress_line_not_the_load_time_warnings(scene, capsys, tmp_path):
    """The explicit coupling at 10 ms does not resolve the boom's oil column: the guard's warnings are printed
    with --no-progress too (which only leaves out the progress line)."""
    code, _, err = hydroplant("run", scene / SCENARIO, "--coupling", "explicit", "--dt", "0.01", "--duration", "0.01",
                              "--no-progress", "--out", tmp_path / "x.mcap", capsys=capsys)
    warnings = [line for line in err if line.startswith("hydroplant: warning: ")]
    assert len(warnings) == 2 and "boom_cyl" in warnings[0] and "explicit coupling" in warnings[0], err
    assert "relief 'relief'" in warnings[1] and len(err) == 2
