"""The command line's parsers, declared without loading any simulation code.

``hydroplant --help`` and ``hydroplant CMD --help`` build every parser from this module alone
(argparse, pathlib and :mod:`sim.methods`): NumPy, numba, MuJoCo and the tool modules are imported
only when a command runs.  Each tool command's ``func`` is a :class:`Lazy` that imports its module
then and calls ``module.main(args) -> int``.

Every option's help names its unit and its allowed values.  The exit statuses are
:data:`EXIT_CODES` (printed by ``hydroplant --help`` and documented in docs/user-guide.md).
"""

from __future__ import annotations

import argparse
import importlib
from pathlib import Path

from sim.methods import COUPLINGS, DEFAULT_COUPLING, DEFAULT_METHODS_HELP, METHOD_HELP, MODES

EXIT_OK = 0
EXIT_FAILED = 1  # check: a check failed; log info: damage found; log recover: data skipped
EXIT_BAD_INPUT = 2
EXIT_DIVERGED = 3
EXIT_PARTIAL = 4  # finished, some parts (runs, settings, map points) failed or diverged
EXIT_INTERRUPTED = 130  # 128 + SIGINT; SIGTERM gives 143, SIGHUP 129

EXIT_CODES = (
    (EXIT_OK, "success: every part finished as asked"),
    (EXIT_FAILED, "check: a check failed; log info: the log is damaged; log recover: data was skipped"),
    (EXIT_BAD_INPUT, "bad input: one line names the file, the field and the allowed range"),
    (EXIT_DIVERGED, "run: the run diverged or was stopped by the plausibility monitor (the log is kept)"),
    (EXIT_PARTIAL, "compare, tradeoff, stability: finished and wrote every report, but some runs, settings or map "
                   "points diverged or failed (listed in the report and the --json output)"),
    (130, "interrupted by Ctrl-C (SIGINT); 143 by SIGTERM, 129 by SIGHUP (a run's log is finished, marked incomplete)"),
)

FIDELITY_CHOICES = ("incompressible", "compressible", "lines")  # hydraulics.network.FIDELITIES


def exit_code_epilog() -> str:
    return "exit status:\n" + "\n".join(f"  {code:<4d} {text}" for code, text in EXIT_CODES)


# ---------------------------------------------------------------------------------------
# argparse types
# ---------------------------------------------------------------------------------------


def positive_float(text):
    """argparse type: a positive finite number (NaN and inf refused)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"{text!r} must be a positive finite number")
    return value


def non_negative_float(text):
    """argparse type: a finite float >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (value >= 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"{text!r} must be a finite number >= 0")
    return value


def int_in(low: int, high: int | None = None):
    """argparse type: an integer in [low, high], or >= low when ``high`` is None."""

    def parse(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if high is None and value < low:
            raise argparse.ArgumentTypeError(f"{text!r} must be >= {low}")
        if high is not None and not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{text!r} must be an integer in [{low}, {high}]")
        return value

    return parse


def out_path(text):
    """argparse type: a non-empty path without NUL bytes (the rest is checked by :func:`sim.io.files.check_output`)."""
    if not text:
        raise argparse.ArgumentTypeError("an empty file name; name the log file, e.g. logs/run.mcap")
    if "\0" in text:
        raise argparse.ArgumentTypeError(f"{text!r}: a file name may not hold a NUL byte")
    return Path(text)


class Lazy:
    """``func`` of a subcommand: imports ``module`` when called and returns ``module.main(args)``."""

    def __init__(self, module: str):
        self.module = module

    def __call__(self, args) -> int:
        return importlib.import_module(self.module).main(args)

    def __repr__(self) -> str:
        return f"Lazy({self.module!r})"


# ---------------------------------------------------------------------------------------
# Shared options
# ---------------------------------------------------------------------------------------

JSON_HELP = ("print one JSON document on stdout instead of the text report (human-readable lines go to stderr); "
             "its schema: docs/cli-json.md")
EXAMPLE_HELP = "a shipped example scene instead of a file, e.g. boom/lift or excavator/dig (see 'hydroplant examples')"


def add_json(parser) -> None:
    parser.add_argument("--json", action="store_true", help=JSON_HELP)


def add_scenario(parser, *, required_help: str = "scenario TOML file (or --example NAME)") -> None:
    parser.add_argument("scenario", type=Path, nargs="?", help=required_help)
    parser.add_argument("--example", metavar="NAME", help=EXAMPLE_HELP)


def add_method_options(parser, *, dt_help: str = "physics step [s], in [1e-9, 1] (default: the scenario's)") -> None:
    parser.add_argument("--method", metavar="MODE:COUPLING", help=f"mode and coupling in one name: {METHOD_HELP}; "
                        "instead of --mode and --coupling")
    parser.add_argument("--mode", choices=MODES, help="mujoco: MuJoCo steps the bodies; pbd: hydroplant's XPBD solver; "
                        "pbd-naive: the naive XPBD co-simulation (always explicit) (default: the scenario's)")
    parser.add_argument("--coupling", choices=COUPLINGS, help="rosenbrock: no Newton solve on most steps; implicit: "
                        "backward Euler with Newton; implicit-linear: no finishing Newton solve; explicit: the "
                        f"co-simulation baseline (default: the scenario's, else {DEFAULT_COUPLING})")
    parser.add_argument("--dt", type=positive_float, help=dt_help)


# ---------------------------------------------------------------------------------------
# Commands
# ---------------------------------------------------------------------------------------


def add_run(sub) -> argparse.ArgumentParser:
    run = sub.add_parser("run", help="run a scenario and write an MCAP log",
                         description="Run a scenario and write an MCAP log. Exit 0: complete; 3: diverged (the log is "
                                     "kept); 2: bad input.", epilog=exit_code_epilog(),
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scenario(run)
    add_method_options(run)
    run.add_argument("--duration", type=positive_float, help="simulated time [s], > 0 (default: the scenario's)")
    run.add_argument("--substeps", type=int_in(1), help="hydraulic substeps per physics step, integer >= 1 (MuJoCo mode)")
    run.add_argument("--pbd-substeps", type=int_in(1), help="XPBD substeps per step, integer >= 1 (PBD modes)")
    run.add_argument("--iterations", type=int_in(1), help="XPBD iterations per substep, integer >= 1 (PBD modes)")
    run.add_argument("--pbd-blend", action="store_true",
                     help="PBD mode: blend the rows' pressure forces by MuJoCo mode's θ-rule (default θ = 1, backward Euler)")
    run.add_argument("--out", type=out_path, help="log file (default: logs/<scene>-<scenario>-<mode>-<coupling>-<time>.mcap); "
                     "an existing file is refused unless --overwrite")
    run.add_argument("--overwrite", action="store_true",
                     help="replace an existing --out file (never the run's inputs, nor anything but a regular file)")
    run.add_argument("--no-progress", action="store_true",
                     help="no progress line (it is shown only when stderr is a terminal, on runs over 3 s)")
    run.add_argument("--no-monitor", action="store_true",
                     help="a state beyond the plausibility bounds (stroke, pressure, energy residual, loop closures, joint "
                          "ranges) is logged as a warning and the run goes on, instead of stopping it with exit status 3")
    run.add_argument("--replay", type=Path, metavar="LOG",
                     help="run a 'hydroplant play' log's recorded commands again, as fast as it goes (bit for bit)")
    run.add_argument("--resume", type=Path, metavar="LOG",
                     help="continue a 'hydroplant play' log's run from its snapshot at or before --at, with its "
                          "recorded commands (bit for bit the original from there)")
    run.add_argument("--at", type=non_negative_float, metavar="T", help="simulated time to resume from [s], >= 0 (with --resume)")
    add_json(run)
    return run


def add_log(sub) -> argparse.ArgumentParser:
    log = sub.add_parser("log", help="inspect, repair or export logs")
    log_sub = log.add_subparsers(dest="log_command", required=True, parser_class=type(log))
    info = log_sub.add_parser("info", help="summary of a log; checks every chunk's CRC",
                              description="Summary of a log (metadata, status, topics, attachments). Every chunk is "
                              "decompressed and its CRC checked unless --no-verify. Exit 0: no damage found (an "
                              "unfinished log is marked UNFINISHED); 1: damaged (see 'log recover'); 2: not an MCAP "
                              "file.")
    info.add_argument("log", type=Path, help="an MCAP log file")
    info.add_argument("--no-verify", action="store_true", help="do not decompress the chunks to check their CRCs")
    add_json(info)
    recover = log_sub.add_parser("recover", help="rebuild a valid MCAP from a cut or damaged log",
                                 description="Write a finished, indexed log from every chunk of PARTIAL that checks; "
                                 "damaged chunks and records are skipped and reported (chunks, messages, byte ranges). "
                                 "OUT defaults to NAME.recovered.mcap and is never replaced unless --overwrite. "
                                 "Exit 0: nothing was skipped; 1: data was skipped; 2: not an MCAP file or OUT exists.")
    recover.add_argument("partial", type=Path, help="the cut or damaged log (e.g. run.mcap.partial)")
    recover.add_argument("out", type=Path, nargs="?", help="the rebuilt log (default: NAME.recovered.mcap)")
    recover.add_argument("--overwrite", action="store_true", help="replace an existing OUT")
    export = log_sub.add_parser("export", help="a log's topics as CSV files or one HDF5 file",
                                description="Write every numeric topic of a log (or those of --topics) as CSV (one file "
                                "per topic: a t column [s] and one column per field, SI units as the field names say) or "
                                "HDF5 (one group per topic, one dataset per field; needs h5py: pip install "
                                "'hydroplant[hdf5]'). Existing files are never replaced unless --overwrite. Exit 0: "
                                "written; 2: not a readable log, an unknown topic, or an output that exists.")
    export.add_argument("log", type=Path, help="a finished MCAP log file")
    export.add_argument("--format", choices=("csv", "hdf5"), default="csv", help="csv (default) or hdf5")
    export.add_argument("--out", type=Path, help="CSV: the folder to write into (default: LOG's name + '-csv' beside it); "
                        "HDF5: the file (default: LOG's name with .h5 beside it)")
    export.add_argument("--topics", nargs="+", metavar="TOPIC",
                        help="the topics to export, e.g. /hydroplant/cylinders/boom_cyl (default: every topic with "
                             "numeric fields)")
    export.add_argument("--overwrite", action="store_true", help="replace existing output files")
    add_json(export)
    return log


def add_inspect(sub) -> argparse.ArgumentParser:
    parser = sub.add_parser("inspect", help="print what a scenario builds and its stability verdict")
    add_scenario(parser)
    add_method_options(parser)
    add_json(parser)
    parser.set_defaults(func=Lazy("sim.tools.inspect"))
    return parser


def add_check(sub) -> argparse.ArgumentParser:
    parser = sub.add_parser("check", help="static checks of a scene: strokes, sweeps, holding pressures, signs, loop closures",
                            description="Static checks of each scene. Exit 0: every check passed; 1: a check failed "
                                        "(marked !!); 2: bad input.")
    parser.add_argument("scenario", type=Path, nargs="*", help="scenario TOML file(s)")
    parser.add_argument("--example", metavar="NAME", action="append",
                        help=EXAMPLE_HELP + "; may be given more than once")
    parser.add_argument("--examples", action="store_true", help="check every shipped example scene")
    parser.add_argument("--mode", choices=MODES, help="validate for this mode (its warnings and refusals): "
                        + ", ".join(MODES) + " (default: the scenario's)")
    parser.add_argument("--grid", type=int_in(0, 1000), default=0, metavar="N",
                        help="also the worst holding pressure over an N-point grid of the cylinders' driving joints "
                             "(integer in [0, 1000]; 0, the default, skips it)")
    add_json(parser)
    parser.set_defaults(func=Lazy("sim.tools.check"))
    return parser


def add_stability(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("stability", help="stability map of a scenario at the extremes (dt, bulk modulus, mass, dead volume, events)",
                       description="Stability map: every method over dt and the extremes. Exit 0: no run diverged or "
                                   "failed; 4: the map is written but some runs diverged or failed; 2: bad input.")
    add_scenario(p)
    p.add_argument("--out", type=Path, help="output directory (default logs/stability-<scene>-<scenario>)")
    p.add_argument("--quick", action="store_true", help="small grid and short runs (for tests)")
    p.add_argument("--scheduler", help="Dask scheduler address tcp://host:port (default: a local process pool)")
    p.add_argument("--workers", type=int_in(1, 1024), help="worker processes, integer in [1, 1024] (default: all cores)")
    p.add_argument("--worker-timeout", type=positive_float, metavar="S",
                   help="longest wait for a first Dask worker to join --scheduler [s], > 0 (default 60); a scheduler "
                   "without workers after that is bad input (exit 2)")
    p.add_argument("--dt", type=_float_list, help="comma-separated physics steps [s] in (0, 1], fractions allowed (e.g. 1e-4,1e-3,1/30)")
    p.add_argument("--methods", type=method_list, help="comma-separated methods, " + METHOD_HELP + "; also pbd:rosenbrock+blend "
                   f"({DEFAULT_METHODS_HELP})")
    p.add_argument("--sweeps", type=_name_list(("beta", "mass", "dead", "event")),
                   help="comma-separated subset of beta (bulk modulus), mass (mass scale), dead (dead volume), event "
                        "(default: all four)")
    p.add_argument("--tolerance", type=positive_float, help="largest relative error of a stable-accurate run [-], > 0 (default 0.05)")
    p.add_argument("--keep-logs", action="store_true", help="keep the MCAP log of every run")
    p.add_argument("--check", action="store_true", help="only print the load-time guards of the scenario (no runs)")
    add_json(p)
    p.set_defaults(func=Lazy("sim.tools.stability"))
    return p


def add_compare(sub) -> argparse.ArgumentParser:
    parser = sub.add_parser(
        "compare", help="runs of a scenario (or existing logs) against a converged reference: table, figures, merged log",
        description="compare SCENARIO [--methods ...]: reference + each method; compare REF.mcap RUN.mcap ...: existing "
                    "logs (the first is the reference). Exit 0: every run stable; 4: the report is written but some "
                    "runs diverged or did not complete; 2: bad input.")
    parser.add_argument("inputs", nargs="*", type=Path, help="a scenario TOML file, or two or more MCAP logs")
    parser.add_argument("--example", metavar="NAME", help=EXAMPLE_HELP)
    parser.add_argument("--methods", "--modes", dest="modes", metavar="METHODS",
                        help="comma-separated runs, each " + METHOD_HELP + f" ({DEFAULT_METHODS_HELP}; a bare mode takes the scenario's coupling)")
    parser.add_argument("--dt", type=positive_float, help="physics step of the runs [s] (default: the scenario's)")
    parser.add_argument("--duration", type=positive_float, help="simulated time [s] (default: the scenario's)")
    parser.add_argument("--out", type=Path, help="output directory (default: logs/compare-<scene>-<scenario>)")
    parser.add_argument("--tolerance", type=positive_float, help="relative convergence tolerance of the reference [-] (default 1e-3)")
    parser.add_argument("--cache", type=Path, help="reference cache directory (default .cache/references)")
    parser.add_argument("--filter-window", type=positive_float, help="also compare the signals averaged over this moving "
                        "window [s] (e.g. 0.1), and check the reference's convergence on them")
    parser.add_argument("--max-steps", type=int_in(1), help="largest reference run [steps], integer >= 1 (default 2 000 000)")
    parser.add_argument("--fresh-reference", action="store_true", help="recompute the reference even if it is cached "
                        "(the cache key covers the scene, circuit and scenario files and the simulation code)")
    parser.add_argument("--fresh", action="store_true", help="ignore every cache (here: the reference's; as --fresh-reference)")
    add_json(parser)
    parser.set_defaults(func=Lazy("sim.tools.compare"))
    return parser


def add_tradeoff(sub) -> argparse.ArgumentParser:
    parser = sub.add_parser("tradeoff", help="sweep modes, couplings and steps: error against cost, Pareto settings",
                            description="Accuracy against cost over modes, couplings, steps and fidelity levels. Exit 0: "
                                        "every setting ran stable; 4: the report is written but some settings diverged "
                                        "or failed; 2: bad input.")
    add_scenario(parser)
    parser.add_argument("--scheduler", help="Dask scheduler address tcp://host:port (default: local process pool)")
    parser.add_argument("--workers", type=int_in(1, 1024), help="local worker processes, integer in [1, 1024] (default: CPU count)")
    parser.add_argument("--worker-timeout", type=positive_float, metavar="S",
                        help="longest wait for a first Dask worker to join --scheduler [s], > 0 (default 60); a scheduler "
                        "without workers after that is bad input (exit 2)")
    parser.add_argument("--out", type=Path, help="output directory (default: logs/tradeoff-<scene>-<scenario>)")
    parser.add_argument("--quick", action="store_true", help="a few settings, one run each")
    parser.add_argument("--duration", type=positive_float, help="simulated time [s] (default: the scenario's)")
    parser.add_argument("--repeats", type=int_in(1), help="timed runs per setting, integer >= 1 (default 3, quick 1)")
    parser.add_argument("--modes", help="comma-separated subset of " + ", ".join(MODES) + " (default: those available); "
                        "each mode is swept over its couplings")
    parser.add_argument("--tolerance", type=positive_float, help="relative convergence tolerance of the reference [-] (default 1e-3)")
    parser.add_argument("--fresh-reference", action="store_true", help="recompute the reference even if it is cached")
    parser.add_argument("--fresh", action="store_true", help="ignore every cache: the reference and every setting computed again")
    parser.add_argument("--fidelities", help="comma-separated fidelity levels to sweep, of " + ", ".join(FIDELITY_CHOICES)
                        + " (default: all; quick: the scenario's and incompressible)")
    parser.add_argument("--reference-fidelity", choices=FIDELITY_CHOICES, help="fidelity of the reference (default: the scenario's)")
    parser.add_argument("--filter-window", type=positive_float, help="compare signals averaged over a centred moving window [s] "
                        "(reference convergence and errors; default: point-wise)")
    add_json(parser)
    parser.set_defaults(func=Lazy("sim.tools.tradeoff"))
    return parser


PLAY_OVERRUNS = ("catch-up", "slow")  # sim.run.play.OVERRUNS
PLAY_INPUTS = ("script", "none", "keyboard", "gamepad", "foxglove")  # sim.run.play.INPUTS


def add_play(sub) -> argparse.ArgumentParser:
    parser = sub.add_parser(
        "play", help="run a scenario paced to the wall clock, driven by an operator; record, replay, resume",
        description="Steps the scenario in frames paced to the wall clock (default 60 Hz, real time), reading the "
        "operator's commands each frame, and writes the run's log with the commands, the frame timing and full-state "
        "snapshots. The frame statistics (median, p99, max, misses) are printed at the end.",
        epilog=exit_code_epilog(), formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scenario(parser)
    parser.add_argument("--mode", choices=MODES, help="mujoco or pbd (default: the scenario's)")
    parser.add_argument("--coupling", choices=COUPLINGS,
                        help="MuJoCo mode's coupling (default: the scenario's)")
    parser.add_argument("--dt", type=positive_float, help="physics step [s], > 0 (default: the scenario's)")
    parser.add_argument("--duration", type=positive_float, help="simulated time [s], > 0 (default: the scenario's)")
    parser.add_argument("--substeps", type=int_in(1), help="hydraulic substeps per physics step, integer >= 1")
    parser.add_argument("--pbd-substeps", type=int_in(1), help="XPBD substeps per step, integer >= 1 (PBD mode)")
    parser.add_argument("--rate", type=positive_float, default=60.0, help="frame rate [Hz], > 0 (default 60)")
    parser.add_argument("--pace", type=non_negative_float, default=1.0,
                        help="simulated seconds per wall-clock second, >= 0 (default 1: real time; 0: as fast as possible)")
    parser.add_argument("--overrun", choices=PLAY_OVERRUNS, default="catch-up",
                        help="a frame that ends after its deadline: catch-up (default: later frames run back to back) or "
                             "slow (the simulated clock falls behind)")
    parser.add_argument("--snapshot-hz", type=non_negative_float, default=1.0,
                        help="full-state snapshots per simulated second, >= 0 (default 1; 0: only at the start)")
    parser.add_argument("--input", choices=PLAY_INPUTS, default="script",
                        help="command source: script (the scenario's [inputs] played at the frame rate, default), none "
                             "(hold the start values), keyboard (keys in the --view window), gamepad (extra 'gamepad'), "
                             "foxglove (a client publishing on /hydroplant/commands; extra 'live')")
    parser.add_argument("--pattern", choices=("iso", "sae"), default="iso",
                        help="excavator control pattern for --input keyboard or gamepad when the scenario has no "
                             "[mapping]: iso (ISO 10968 / SAE J1177, default) or sae (SAE J1814: boom and stick swapped)")
    parser.add_argument("--view", action="store_true",
                        help="show the machine in MuJoCo's viewer with the hydraulic state overlaid (pressures in bar, "
                             "valve commands, frame budget) and the cylinders drawn between their pins")
    parser.add_argument("--foxglove", type=int_in(0, 65535), nargs="?", const=8765, metavar="PORT",
                        help="serve a live Foxglove stream on ws://127.0.0.1:PORT, port in [0, 65535] (default 8765; "
                             "extra 'live')")
    parser.add_argument("--replay", type=Path, metavar="LOG", help="play a log's recorded commands again (paced)")
    parser.add_argument("--resume", type=Path, metavar="LOG", help="continue a log's run from its snapshot at or before --at")
    parser.add_argument("--at", type=non_negative_float, metavar="T", help="simulated time to resume from [s], >= 0 (with --resume)")
    parser.add_argument("--out", type=out_path, help="log file (default: logs/<scene>-<scenario>-<mode>-<coupling>-<time>.mcap)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    parser.add_argument("--no-monitor", action="store_true", help="log the plausibility monitor's findings as warnings")
    parser.set_defaults(func=Lazy("sim.run.play"))
    return parser


def add_compile(sub) -> argparse.ArgumentParser:
    parser = sub.add_parser("compile", help="compile every numba kernel into the disk cache, in parallel")
    parser.add_argument("--jobs", type=int_in(1, 64), default=None,
                        help="processes at a time, integer in [1, 64] (default: one per group, at most the CPU count)")
    groups = ("pbd", "mujoco", "xpbd", "hydraulics")  # sim.run.precompile.GROUPS
    parser.add_argument("--groups", nargs="+", choices=groups, default=list(groups),
                        help="kernel groups to compile: " + ", ".join(groups) + " (default: all)")
    parser.set_defaults(func=Lazy("sim.run.precompile"))
    return parser


TOOL_PARSERS = {
    "sim.tools.inspect": add_inspect,
    "sim.tools.check": add_check,
    "sim.tools.stability": add_stability,
    "sim.tools.compare": add_compare,
    "sim.tools.tradeoff": add_tradeoff,
    "sim.run.precompile": add_compile,
    "sim.run.play": add_play,
}
"""Tool module -> the function registering its subcommand (``module.add_parser`` delegates here)."""


# ---------------------------------------------------------------------------------------
# List types
# ---------------------------------------------------------------------------------------


def eval_fraction(text: str) -> float:
    """A number or a fraction like ``1/30``."""
    text = text.strip()
    if "/" in text:
        num, _, den = text.partition("/")
        return float(num) / float(den) if float(den) != 0 else float("inf")
    return float(text)


def _float_list(text):
    try:
        values = tuple(float(eval_fraction(v)) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of numbers") from None
    if not values or not all(v > 0 and v < float("inf") for v in values):
        raise argparse.ArgumentTypeError(f"{text!r}: every value must be a positive finite number")
    return values


def method_list(text):
    """argparse type: a comma-separated list of methods (:func:`sim.methods.parse_methods`), as canonical names."""
    from sim.methods import MethodError, parse_methods

    try:
        return tuple(m.name for m in parse_methods(text))
    except MethodError as exc:
        raise argparse.ArgumentTypeError(f"{exc}; choose from MODE or MODE:COUPLING, e.g. mujoco:implicit,pbd-naive") from None


def _name_list(choices):
    def parse(text):
        values = tuple(v.strip() for v in text.split(",") if v.strip())
        bad = [v for v in values if v not in choices]
        if not values or bad:
            raise argparse.ArgumentTypeError(f"{text!r}: choose from {', '.join(choices)}")
        return values

    return parse
