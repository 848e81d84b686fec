"""Command-line conventions: light ``--help``, one method naming scheme, ``--example`` and help text on every
command, progress only on a terminal, documented exit statuses."""

from __future__ import annotations

import io
import re
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import MODELS
from sim import cli
from sim.commands import EXIT_CODES
from sim.methods import COUPLINGS, MODES, Method, MethodError, parse_method, parse_methods
from sim.progress import Progress

ROOT = Path(__file__).resolve().parents[1]
SEED = MODELS / "seed_cylinder" / "closed.scenario.toml"
SCENARIO_COMMANDS = ("run", "inspect", "check", "compare", "tradeoff", "stability")
HEAVY = ("numpy", "numba", "mujoco", "scipy", "matplotlib", "sim.tools.compare", "sim.run.runner")


@pytest.mark.parametrize("argv", [["--help"], ["compare", "--help"], ["run", "--help"], ["--version"]])
def test_help_loads_no_simulation_code(argv):
    """``hydroplant --help`` (and a command's) imports neither numpy, numba nor MuJoCo nor a tool module."""
    code = ("import sys\nfrom sim.cli import main\ntry:\n    main(%r)\nexcept SystemExit:\n    pass\n"
            "print('loaded:', *(m for m in %r if m in sys.modules))" % (argv, HEAVY))
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines()[-1] == "loaded:", result.stdout[-300:]


def test_python_m_hydroplant_is_the_command():
    result = subprocess.run([sys.executable, "-m", "hydroplant", "--help"], capture_output=True, text=True, timeout=60,
                            cwd=ROOT)
    assert result.returncode == 0 and result.stdout.startswith("usage: hydroplant")
    for code, _ in EXIT_CODES:
        assert re.search(rf"^  {code}\s", result.stdout, re.M), code  # the exit statuses in the epilog
    bad = subprocess.run([sys.executable, "-m", "hydroplant", "run", "--dt", "-1"], capture_output=True, text=True,
                         timeout=60, cwd=ROOT)
    assert bad.returncode == 2 and "--dt" in bad.stderr


def test_exit_codes_are_documented_in_the_user_guide():
    guide = (ROOT / "docs" / "user-guide.md").read_text()
    section = guide[guide.index("## Exit status"):]
    for code, _ in EXIT_CODES:
        assert re.search(rf"^\| {code}\b", section, re.M), code


def _option_entries(help_text: str) -> dict:
    """Option -> its help text, from the 'options:' section of a formatted help."""
    section = help_text.split("options:", 1)[1]
    entries, current = {}, None
    for line in section.splitlines():
        match = re.match(r"^  (-[^ ].*?)(?:  +(\S.*))?$", line)
        if match:
            current = match.group(1).split(",")[-1].split()[0]
            entries[current] = match.group(2) or ""
        elif current and line.startswith("      "):
            entries[current] += " " + line.strip()
    return entries


@pytest.mark.parametrize("command", ["run", "inspect", "check", "compare", "tradeoff", "stability", "compile",
                                     "log info", "log recover", "log export"])
def test_every_option_has_help_text(command, capsys):
    with pytest.raises(SystemExit):
        cli.main(command.split() + ["--help"])
    entries = _option_entries(capsys.readouterr().out)
    assert entries and all(text.strip() for text in entries.values()), entries
    numeric = {"--dt": "[s]", "--duration": "[s]", "--tolerance": "[-]", "--filter-window": "[s]"}
    for option, unit in numeric.items():
        if option in entries:
            assert unit in entries[option], (option, entries[option])


@pytest.mark.parametrize("command", SCENARIO_COMMANDS)
def test_every_scenario_command_takes_an_example(command):
    args = cli.build_parser().parse_args([command, "--example", "boom/lift"])
    assert args.example in ("boom/lift", ["boom/lift"])


def test_an_unknown_example_is_bad_input(capsys):
    assert cli.main(["inspect", "--example", "boom/nothing"]) == 2
    assert "boom/nothing" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------
# Method names
# ---------------------------------------------------------------------------------------


def test_method_names_read_and_write_one_spelling():
    for mode in MODES:
        for coupling in COUPLINGS:
            method = parse_method(f"{mode}:{coupling}", warn=None)
            assert (method.mode, method.coupling) == (mode, coupling)
            assert parse_method(method.name, coupling, warn=None) == method  # the name reads back as itself
    assert parse_method("pbd", warn=None) == Method("pbd", "rosenbrock")  # the default coupling
    assert parse_method("mujoco", "rosenbrock", warn=None).name == "mujoco:rosenbrock"  # a bare mode: the default coupling
    assert parse_method("pbd:rosenbrock+blend", warn=None) == Method("pbd", "rosenbrock", True)
    assert Method("pbd", "rosenbrock", True).file_label == "pbd-rosenbrock-blend"
    assert parse_method("pbd-naive:explicit", warn=None).name == "pbd-naive"
    for bad, word in (("bullet", "'bullet' is not one of"), ("mujoco:sideways", "coupling 'sideways'"),
                      ("mujoco:implicit+blend", "PBD-mode option")):
        with pytest.raises(MethodError, match=re.escape(word)):
            parse_method(bad, warn=None)
    with pytest.raises(MethodError, match="listed twice"):
        parse_methods("pbd,pbd:rosenbrock", warn=None)


@pytest.mark.parametrize("old, new", [("mujoco-implicit", "mujoco:implicit"), ("mujoco-implicit-linear", "mujoco:implicit-linear"),
                                      ("pbd-rosenbrock-blend", "pbd:rosenbrock+blend"), ("mujoco-explicit", "mujoco:explicit")])
def test_old_dash_spellings_are_read_with_one_warning(old, new):
    warnings = []
    assert parse_method(old, warn=warnings.append).name == new
    assert len(warnings) == 1 and old in warnings[0] and new in warnings[0] and "deprecated" in warnings[0]
    quiet = []
    parse_method(new, warn=quiet.append)
    parse_method("pbd-naive", warn=quiet.append)
    assert quiet == []


def test_cli_warns_once_for_an_old_spelling_and_uses_the_method(capsys):
    """stability --methods with the dash spelling: one warning line on stderr, the canonical name in the parsed args."""
    args = cli.build_parser().parse_args(["stability", str(SEED), "--methods", "mujoco-explicit,pbd-naive"])
    assert args.methods == ("mujoco:explicit", "pbd-naive")
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["hydroplant: warning: method 'mujoco-explicit' is a deprecated spelling; write 'mujoco:explicit'"]
    from sim.tools.compare import parse_runs

    specs = parse_runs("mujoco-explicit,mujoco", "implicit")
    assert [(s.method, s.label) for s in specs] == [("mujoco:explicit", "mujoco-explicit"), ("mujoco:implicit", "mujoco-implicit")]
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_run_method_option_sets_mode_and_coupling(capsys):
    args = cli.build_parser().parse_args(["run", str(SEED), "--method", "pbd:rosenbrock+blend"])
    assert cli.method_overrides(args) == {"mode": "pbd", "coupling": "rosenbrock", "pbd_blend": True}
    assert cli.main(["run", str(SEED), "--method", "mujoco:explicit", "--coupling", "implicit"]) == 2
    assert "not both" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------
# Progress
# ---------------------------------------------------------------------------------------


class _Stream(io.StringIO):
    def __init__(self, tty: bool):
        super().__init__()
        self.tty = tty

    def isatty(self):
        return self.tty


class _Clock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def test_progress_redraws_with_an_eta_on_a_terminal_and_writes_plain_lines_elsewhere():
    for tty in (True, False):
        stream, clock = _Stream(tty), _Clock()
        progress = Progress(20, "tradeoff", "settings", stream=stream, clock=clock)
        for done in range(1, 21):
            clock.now = 2.0 * done  # 2 s per setting
            progress(done)
        text = stream.getvalue()
        if tty:
            assert text.count("\r") == 20 and text.endswith("tradeoff: 20/20 settings, 40 s\n")
            assert "tradeoff: 5/20 settings, 10 s, ETA 30 s" in text  # 15 left at 2 s each
        else:
            assert "\r" not in text and "\033" not in text
            assert text.splitlines() == [f"tradeoff: {d}/20 settings, {2 * d} s" + (f", ETA {2 * (20 - d)} s" if d < 20 else "")
                                         for d in range(2, 21, 2)]


def test_progress_does_not_count_cached_items_in_the_rate():
    stream, clock = _Stream(True), _Clock()
    progress = Progress(10, "stability", stream=stream, clock=clock)
    progress(5)  # five read from the cache at once
    clock.now = 10.0
    progress(6)  # one computed in 10 s: four left, 40 s
    assert stream.getvalue().splitlines()[-1].endswith("stability: 6/10 runs, 10 s, ETA 40 s")


@pytest.mark.parametrize("tty", [True, False])
def test_run_progress_line_only_on_a_terminal(tty, tmp_path, monkeypatch, capsys):
    """With the progress thresholds at zero every block would redraw the line: on a terminal it is redrawn with
    ``\\r`` and an ETA; into a pipe or file nothing of it is written."""
    from sim.run import runner

    monkeypatch.setattr(runner, "PROGRESS_AFTER", -1.0)
    monkeypatch.setattr(runner, "PROGRESS_EVERY", -1.0)
    stream = _Stream(tty)
    monkeypatch.setattr(sys, "stderr", stream)
    assert cli.main(["run", str(SEED), "--duration", "0.05", "--out", str(tmp_path / "run.mcap")]) == 0
    text = stream.getvalue()
    if tty:
        assert text.count("\r") >= 1 and "s simulated, ETA" in text and text.endswith("\n")
    else:
        assert "\r" not in text and "simulated" not in text
    assert "status        complete" in capsys.readouterr().out
