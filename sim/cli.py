"""The ``hydroplant`` command line.

Subcommands::

    hydroplant run SCENARIO | --example NAME [--mode M] [--coupling C] [--dt S] [--duration S] [--substeps N] [--out PATH]
    hydroplant examples                  the shipped example scenes (names for ``run --example``)
    hydroplant demo                      the hydraulics-only 1-DOF lift (no MuJoCo)
    hydroplant log info LOG [--no-verify]  summary of a log, chunk CRCs checked (exit 1 if damaged)
    hydroplant log recover PARTIAL [OUT] [--overwrite]  rebuild a valid MCAP from a cut or damaged log
                                         (exit 1 if data was skipped)
    hydroplant compile [--jobs N]        fill numba's disk cache with every compiled kernel, in parallel

Bad input (scenario, circuit, MJCF binding, arguments, an output file that may not be
written) prints one line naming the file, the field and the allowed range, and exits with
status 2.  ``run --out`` never replaces an existing file unless ``--overwrite`` is given, and
never the run's inputs or anything that is not a regular file (:func:`sim.io.files.check_output`).

Signals: Ctrl-C (SIGINT), SIGTERM and SIGHUP all stop a command the same way: a run's log is
finished and marked incomplete, one line on stderr names it, and the exit status is 128 + the
signal number (130, 143, 129).  Each signal is recorded, then SIGINT raises
:class:`KeyboardInterrupt` (:func:`_interrupt`) and SIGTERM and SIGHUP are routed to the SIGINT
handler in force (:func:`_forward_signal`), so the log writer's deferral of Ctrl-C while a record
is half written holds for all three.  The handlers are installed first thing in :func:`main`,
before the command's modules (numpy, numba, MuJoCo: most of start-up) are imported, so a signal
at any time after the interpreter has started gives the same exit status.  A signal before any log
is open (start-up, imports; also when a library turns the interrupt into another error, as MuJoCo's
import does) exits quietly; a run asks whether a signal arrived before it opens its log and before
every block, so an interrupt a library swallowed still stops it there.
"""

from __future__ import annotations

import signal
import sys

EXIT_BAD_INPUT = 2
EXIT_DIVERGED = 3
EXIT_INTERRUPTED = 130  # 128 + SIGINT; SIGTERM gives 143, SIGHUP 129

import argparse
from pathlib import Path

FORWARDED_SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))
_received: list[int] = []  # the signals received during main(), first first


def _interrupt(signum, frame):
    """SIGINT handler: remember the signal, then raise :class:`KeyboardInterrupt` as Python's own handler does."""
    _received.append(signum)
    signal.default_int_handler(signum, frame)


def _forward_signal(signum, frame):
    """SIGTERM / SIGHUP handler: remember the signal, then do what SIGINT does now.

    The SIGINT handler in force is Python's (raises :class:`KeyboardInterrupt`) or, while the log
    writer is mid-record, its deferring one (the interrupt is raised when the record is complete).
    """
    _received.append(signum)
    handler = signal.getsignal(signal.SIGINT)
    if handler is _interrupt:
        signal.default_int_handler(signum, frame)
    elif callable(handler):
        handler(signum, frame)
    else:  # SIGINT ignored or default (a background job): SIGTERM still stops the command cleanly
        raise KeyboardInterrupt


def _install_signals() -> dict:
    """SIGINT to :func:`_interrupt` (unless ignored or replaced), SIGTERM and SIGHUP to :func:`_forward_signal`
    (main thread only); the previous handlers."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        return {}
    previous = {}
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        previous[signal.SIGINT] = signal.signal(signal.SIGINT, _interrupt)
    for signum in FORWARDED_SIGNALS:
        if signal.getsignal(signum) == signal.SIG_IGN:
            continue  # ignored by whoever started us (nohup): left ignored
        previous[signum] = signal.signal(signum, _forward_signal)
    return previous


def _interrupted(exc: BaseException | None) -> int:
    """One line when a log was being written (named), nothing before; the exit status 128 + signal."""
    signum = _received[0] if _received else signal.SIGINT
    log_path = getattr(exc, "log_path", None)
    if log_path is not None:
        name = signal.Signals(signum).name
        print(f"\nhydroplant: interrupted ({name}); the log written so far is finished and marked incomplete: {log_path}",
              file=sys.stderr)
    return 128 + int(signum)


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse's own errors also exit 2, on one line
        print(f"hydroplant: error: {message} (see '{self.prog} --help')", file=sys.stderr)
        raise SystemExit(EXIT_BAD_INPUT)


def positive_float(text):
    """argparse type: a positive finite number (NaN and inf refused)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"{text!r} must be a positive finite number")
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


def build_parser() -> argparse.ArgumentParser:
    from sim import version

    parser = _Parser(prog="hydroplant", description="Hydraulic heavy-equipment simulator (SI units throughout).")
    parser.add_argument("--version", action="version", version=f"hydroplant {version()}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    run = sub.add_parser("run", help="run a scenario and write an MCAP log")
    run.add_argument("scenario", type=Path, nargs="?", help="scenario TOML file")
    run.add_argument("--example", metavar="NAME", help="a shipped example instead of a file, e.g. excavator/dig (see 'hydroplant examples')")
    run.add_argument("--mode", choices=("mujoco", "pbd", "pbd-naive"))
    run.add_argument("--coupling", choices=("implicit", "explicit", "implicit-linear", "rosenbrock"))  # sim.io.scenario.COUPLINGS
    run.add_argument("--dt", type=positive_float, help="physics step [s]")
    run.add_argument("--duration", type=positive_float, help="simulated time [s]")
    run.add_argument("--substeps", type=int_in(1), help="hydraulic substeps per physics step")
    run.add_argument("--pbd-substeps", type=int_in(1), help="XPBD substeps per step (PBD mode)")
    run.add_argument("--iterations", type=int_in(1), help="XPBD iterations per substep (PBD mode)")
    run.add_argument("--pbd-blend", action="store_true",
                     help="PBD mode: blend the rows' pressure forces by MuJoCo mode's θ-rule (default θ = 1, backward Euler)")
    run.add_argument("--out", type=out_path, help="log file (default: logs/<scene>-<scenario>-<mode>-<coupling>-<time>.mcap); "
                     "an existing file is refused unless --overwrite")
    run.add_argument("--overwrite", action="store_true",
                     help="replace an existing --out file (never the run's inputs, nor anything but a regular file)")
    run.add_argument("--no-progress", action="store_true", help="no progress line (warnings are still printed)")
    run.add_argument("--no-monitor", action="store_true",
                     help="a state beyond the plausibility bounds (stroke, pressure, energy residual, loop closures, joint "
                          "ranges) is logged as a warning and the run goes on, instead of stopping it with exit status 3")
    from sim.run.play import add_run_options

    add_run_options(run)  # --replay LOG, --resume LOG --at T

    sub.add_parser("examples", help="list the shipped example scenes")
    sub.add_parser("demo", help="hydraulics-only demo: pump, valve and cylinder lifting a 1-DOF mass")

    log = sub.add_parser("log", help="inspect or repair logs")
    log_sub = log.add_subparsers(dest="log_command", required=True, parser_class=_Parser)
    info = log_sub.add_parser("info", help="summary of a log; checks every chunk's CRC",
                              description="Summary of a log (metadata, status, topics, attachments). Every chunk is "
                              "decompressed and its CRC checked unless --no-verify. Exit 0: no damage found (an "
                              "unfinished log is marked UNFINISHED); 1: damaged (see 'log recover'); 2: not an MCAP "
                              "file.")
    info.add_argument("log", type=Path)
    info.add_argument("--no-verify", action="store_true", help="do not decompress the chunks to check their CRCs")
    recover = log_sub.add_parser("recover", help="rebuild a valid MCAP from a cut or damaged log",
                                 description="Write a finished, indexed log from every chunk of PARTIAL that checks; "
                                 "damaged chunks and records are skipped and reported (chunks, messages, byte ranges). "
                                 "OUT defaults to NAME.recovered.mcap and is never replaced unless --overwrite. "
                                 "Exit 0: nothing was skipped; 1: data was skipped; 2: not an MCAP file or OUT exists.")
    recover.add_argument("partial", type=Path)
    recover.add_argument("out", type=Path, nargs="?")
    recover.add_argument("--overwrite", action="store_true", help="replace an existing OUT")
    for module in _tool_modules():
        module.add_parser(sub)
    return parser


# Tool subcommands living in their own modules: each module has ``add_parser(subparsers)``,
# which registers one subcommand whose ``func`` default is ``module.main(args) -> int``.
TOOL_MODULES = ("sim.tools.inspect", "sim.tools.check", "sim.tools.stability", "sim.tools.compare", "sim.tools.tradeoff", "sim.run.precompile",
                "sim.run.play")


def _tool_modules():
    import importlib

    return [importlib.import_module(name) for name in TOOL_MODULES]


def _run(args) -> int:
    from hydraulics.components import CircuitError
    from sim.io.examples import example_path
    from sim.run.play import run_from_log
    from sim.run.runner import run

    result = run_from_log(args)  # --replay LOG, --resume LOG --at T
    if result is not None:
        print(result.summary_text())
        return 0 if result.status == "complete" else EXIT_DIVERGED

    overrides = {
        "mode": args.mode,
        "coupling": args.coupling,
        "dt": args.dt,
        "duration": args.duration,
        "hydraulic_substeps": args.substeps,
        "pbd_substeps": args.pbd_substeps,
        "pbd_iterations": args.iterations,
        "pbd_blend": True if args.pbd_blend else None,
        "monitor": False if args.no_monitor else None,
    }
    if (args.scenario is None) == (args.example is None):
        raise CircuitError("run: give either a SCENARIO file or --example NAME (see 'hydroplant examples')")
    scenario = example_path(args.example) if args.example else args.scenario
    result = run(scenario, out=args.out, overrides=overrides, progress=not args.no_progress, overwrite=args.overwrite,
                 stop=_received.__len__, warn=True)  # a signal whose interrupt a library swallowed still stops the run
    print(result.summary_text())
    return 0 if result.status == "complete" else EXIT_DIVERGED


def _log(args) -> int:
    """``log info`` (exit 0 no damage found, 1 damaged) and ``log recover`` (exit 0 nothing skipped, 1 data
    skipped); a file that is not a readable MCAP log raises CircuitError (exit 2)."""
    from hydraulics.components import CircuitError
    from sim.io.mcap_log import inspect_log, recover

    path = args.log if args.log_command == "info" else args.partial
    if not path.is_file():
        raise CircuitError(f"{path}: log file not found" if not path.exists() else f"{path}: not a regular file")
    try:
        if args.log_command == "info":
            text, code = inspect_log(path, verify=not args.no_verify)
            print(text)
            return code
        out = args.out or path.with_name(path.name.removesuffix(".partial").removesuffix(".mcap") + ".recovered.mcap")
        report = recover(path, out, overwrite=args.overwrite)
    except CircuitError:
        raise
    except (OSError, ValueError, EOFError, LookupError) as exc:
        raise CircuitError(f"{path}: not a readable MCAP log ({type(exc).__name__}: {exc})") from None
    print(report.summary_text())
    print(f"recovered log: {out}")
    return 0 if report.complete else 1


def main(argv=None) -> int:
    _received.clear()
    previous = _install_signals()
    try:
        status = _main(argv)
        # A signal whose interrupt a library turned into an error it then handled (an import fallback)
        # still stops the command as the signal asks.
        return _interrupted(None) if _received else status
    except KeyboardInterrupt as exc:
        return _interrupted(exc)
    except Exception:
        if _received:  # the interrupt became another error inside a library (MuJoCo's import: "initialization failed")
            return _interrupted(None)
        raise
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _main(argv) -> int:
    from hydraulics.components import CircuitError  # (here, not at the top: after main() installed the handlers)

    args = build_parser().parse_args(argv)
    try:
        if args.command == "run":
            return _run(args)
        if args.command == "examples":
            from sim.io.examples import examples

            for name, summary in examples():
                print(f"{name:24} {summary}")
            return 0
        if args.command == "demo":
            from sim.tools.demo import main as demo

            return demo()
        if args.command == "log":
            return _log(args)
        return args.func(args)
    except CircuitError as exc:  # ScenarioError is a CircuitError
        print(f"hydroplant: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:  # writing the log: a full disk, a folder made read-only during the run, ...
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        print(f"hydroplant: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return EXIT_BAD_INPUT


def _one_line(exc: BaseException) -> str:
    """The exception's message on one line (a newline in a file name or a library's message joined)."""
    return " ".join(str(exc).split("\n"))


if __name__ == "__main__":
    raise SystemExit(main())
