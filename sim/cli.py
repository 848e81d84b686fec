"""The ``hydroplant`` command line.

Subcommands::

    hydroplant run SCENARIO | --example NAME [--method MODE:COUPLING | --mode M --coupling C] [--dt S] [--duration S]
                   [--substeps N] [--out PATH] [--json]
    hydroplant examples                  the shipped example scenes (names for ``--example``)
    hydroplant demo                      the hydraulics-only 1-DOF lift (no MuJoCo)
    hydroplant inspect|check|compare|tradeoff|stability SCENARIO | --example NAME ... [--json]
    hydroplant log info LOG [--no-verify] [--json]  summary of a log, chunk CRCs checked (exit 1 if damaged)
    hydroplant log recover PARTIAL [OUT] [--overwrite]  rebuild a valid MCAP from a cut or damaged log
                                         (exit 1 if data was skipped)
    hydroplant log export LOG --format csv|hdf5 [--out PATH] [--topics T ...] [--overwrite]
    hydroplant compile [--jobs N]        fill numba's disk cache with every compiled kernel, in parallel
    python -m hydroplant ...             the same

The parsers are declared in :mod:`sim.commands` and built without importing NumPy, numba, MuJoCo
or a tool module (``hydroplant --help`` loads none of them); a command imports what it needs when
it runs.  ``--json`` prints one JSON document on stdout, valid against the command's schema in
``sim/schemas`` (docs/cli-json.md), and sends every human-readable line to stderr.

Exit status (:data:`sim.commands.EXIT_CODES`): 0 success; 1 a check failed / a log is damaged;
2 bad input; 3 a run diverged; 4 compare, tradeoff or stability finished with some runs diverged
or failed; 128 + signal when interrupted.

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

try:  # Ctrl-C while the modules load: a quiet exit, no traceback
    import argparse

    from sim import version
    from sim.commands import (EXIT_BAD_INPUT, EXIT_DIVERGED, EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, EXIT_PARTIAL,
                              TOOL_PARSERS, add_log, add_run, exit_code_epilog, int_in, out_path, positive_float)
except KeyboardInterrupt:
    raise SystemExit(130) from None

__all__ = ["EXIT_BAD_INPUT", "EXIT_DIVERGED", "EXIT_FAILED", "EXIT_INTERRUPTED", "EXIT_OK", "EXIT_PARTIAL", "TOOL_MODULES",
           "build_parser", "int_in", "main", "out_path", "positive_float"]

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


class _Version(argparse.Action):
    """``--version``: the version is looked up only when asked (the package metadata costs tens of ms to read)."""

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"hydroplant {version()}")
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    """Every subcommand's parser, from the declarations of :mod:`sim.commands` (nothing heavy is imported)."""
    parser = _Parser(prog="hydroplant", description="Hydraulic heavy-equipment simulator (SI units throughout). "
                     "'hydroplant CMD --help' lists a command's options with units and allowed values; "
                     "--json on run, inspect, check, compare, tradeoff, stability and log info|export prints "
                     "one JSON document (docs/cli-json.md).",
                     epilog=exit_code_epilog(), formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action=_Version, nargs=0, help="print the installed version and exit")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    add_run(sub)
    sub.add_parser("examples", help="list the shipped example scenes (names for --example)")
    sub.add_parser("demo", help="hydraulics-only demo: pump, valve and cylinder lifting a 1-DOF mass")
    add_log(sub)
    for name in TOOL_MODULES:
        if name in TOOL_PARSERS:
            TOOL_PARSERS[name](sub)
        else:  # a tool module of its own: its add_parser registers the subcommand
            import importlib

            importlib.import_module(name).add_parser(sub)
    return parser


# Tool subcommands living in their own modules: each module has ``main(args) -> int``; its parser is
# declared in :data:`sim.commands.TOOL_PARSERS` (or, for a module not there, by its ``add_parser(subparsers)``).
TOOL_MODULES = ("sim.tools.inspect", "sim.tools.check", "sim.tools.stability", "sim.tools.compare", "sim.tools.tradeoff", "sim.run.precompile",
                "sim.run.play")


def scenario_argument(args, command: str):
    """The scenario of a command: its SCENARIO file or ``--example NAME`` (exactly one); bad input raises CircuitError."""
    from hydraulics.components import CircuitError

    from sim.io.examples import example_path

    given = getattr(args, "scenario", None)
    example = getattr(args, "example", None)
    if (given is None) == (example is None):
        raise CircuitError(f"{command}: give either a SCENARIO file or --example NAME (see 'hydroplant examples')")
    return example_path(example) if example else given


def method_overrides(args) -> dict:
    """``mode`` and ``coupling`` from ``--method`` or ``--mode``/``--coupling`` (not both); bad input raises CircuitError."""
    from hydraulics.components import CircuitError

    from sim.methods import MethodError, parse_method

    method = getattr(args, "method", None)
    if method is None:
        return {"mode": getattr(args, "mode", None), "coupling": getattr(args, "coupling", None)}
    if args.mode is not None or args.coupling is not None:
        raise CircuitError("--method: give either --method MODE:COUPLING or --mode/--coupling, not both")
    try:
        parsed = parse_method(method)
    except MethodError as exc:
        raise CircuitError(f"--method: {exc}") from None
    return {"mode": parsed.mode, "coupling": parsed.coupling, "pbd_blend": True if parsed.blend else None}


def _run(args) -> int:
    from hydraulics.components import CircuitError
    from sim.io.examples import example_path
    from sim.run.play import run_from_log
    from sim.run.runner import run

    result = run_from_log(args)  # --replay LOG, --resume LOG --at T
    if result is not None:
        print(result.summary_text())
        return EXIT_OK if result.status == "complete" else EXIT_DIVERGED

    methods = method_overrides(args)
    overrides = {
        "mode": methods["mode"],
        "coupling": methods["coupling"],
        "dt": args.dt,
        "duration": args.duration,
        "hydraulic_substeps": args.substeps,
        "pbd_substeps": args.pbd_substeps,
        "pbd_iterations": args.iterations,
        "pbd_blend": True if args.pbd_blend or methods.get("pbd_blend") else None,
        "monitor": False if args.no_monitor else None,
    }
    scenario = scenario_argument(args, "run")
    result = run(scenario, out=args.out, overrides=overrides, progress=not args.no_progress, overwrite=args.overwrite,
                 stop=_received.__len__, warn=True)  # a signal whose interrupt a library swallowed still stops the run
    code = EXIT_OK if result.status == "complete" else EXIT_DIVERGED
    if args.json:
        from sim.jsonout import emit, run_document

        print(result.summary_text(), file=sys.stderr)
        emit(run_document(result, code))
    else:
        print(result.summary_text())
    return code


def _log(args) -> int:
    """``log info`` (exit 0 no damage found, 1 damaged), ``log recover`` (exit 0 nothing skipped, 1 data
    skipped) and ``log export``; a file that is not a readable MCAP log raises CircuitError (exit 2)."""
    from hydraulics.components import CircuitError

    from sim.io.mcap_log import inspect_log, recover

    path = args.partial if args.log_command == "recover" else args.log
    if not path.is_file():
        raise CircuitError(f"{path}: log file not found" if not path.exists() else f"{path}: not a regular file")
    try:
        if args.log_command == "info":
            text, code = inspect_log(path, verify=not args.no_verify)
            if args.json:
                from sim.io.log_reader import log_summary
                from sim.jsonout import emit

                emit({"command": "log info", **log_summary(path, verify=not args.no_verify), "exit_code": code})
            else:
                print(text)
            return code
        if args.log_command == "export":
            from sim.io.log_export import export_log

            report = export_log(path, args.format, out=args.out, topics=args.topics, overwrite=args.overwrite)
            if args.json:
                from sim.jsonout import emit

                emit({"command": "log export", "status": "ok", "exit_code": EXIT_OK, **report})
            else:
                print(f"{len(report['topics'])} topic(s) exported as {args.format}: " + ", ".join(report["files"]))
            return EXIT_OK
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
    args = build_parser().parse_args(argv)  # (--help and bad options end here, before any simulation code loads)
    from hydraulics.components import CircuitError  # (here, not at the top: after main() installed the handlers)

    args.stop = _received.__len__  # a signal whose interrupt a library swallowed still stops a command's runs
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
        return _bad_input(args, _one_line(exc))
    except OSError as exc:  # writing the log: a full disk, a folder made read-only during the run, ...
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        return _bad_input(args, f"{where}{exc.strerror or exc}")


def _bad_input(args, message: str) -> int:
    """One line on stderr; with --json also the error document on stdout; exit status 2."""
    print(f"hydroplant: error: {message}", file=sys.stderr)
    if getattr(args, "json", False):
        from sim.jsonout import emit

        command = args.command + (f" {args.log_command}" if args.command == "log" else "")
        emit({"command": command, "status": "error", "exit_code": EXIT_BAD_INPUT, "error": message})
    return EXIT_BAD_INPUT


def _one_line(exc: BaseException) -> str:
    """The exception's message on one line (a newline in a file name or a library's message joined)."""
    return " ".join(str(exc).split("\n"))


if __name__ == "__main__":
    raise SystemExit(main())
