"""``--json`` output of the command line: one JSON document on stdout, valid against a schema shipped in the package.

Every document is an object with at least ``command`` (``"run"``, ``"compare"``, ``"log info"`` …),
``status`` (a word saying how it went, fixed per command, see docs/cli-json.md) and ``exit_code``
(the process's exit status).  Numbers are SI (field names carry the unit: ``_s``, ``_m``, ``_pa``,
``_j``); a quantity that is not finite (NaN, ±inf) is ``null``.  Paths are strings as given or as
written.  The schemas (JSON Schema draft 2020-12) are ``sim/schemas/<name>.schema.json``; read one
with :func:`schema`.

Example::

    hydroplant run --example boom/lift --duration 0.1 --json | python -c "import json,sys; print(json.load(sys.stdin)['final_strokes_m'])"
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

SCHEMA_NAMES = ("run", "compare", "tradeoff", "stability", "inspect", "check", "log-info", "log-export", "error")


def plain(value):
    """``value`` as JSON types: non-finite floats ``None``, paths and other objects as strings, numpy scalars as numbers."""
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, set, frozenset)):
        return [plain(v) for v in value]
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, int):
        return int(value)
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Path):
        return str(value)
    if hasattr(value, "item") and callable(value.item):  # numpy scalar
        return plain(value.item())
    return str(value)


def emit(document: dict, stream=None) -> None:
    """Print ``document`` (made :func:`plain`) as one line of strict JSON on stdout."""
    print(json.dumps(plain(document), allow_nan=False, ensure_ascii=False), file=stream or sys.stdout, flush=True)


def schema(name: str) -> dict:
    """The JSON Schema of a command's document (``name`` one of :data:`SCHEMA_NAMES`)."""
    from importlib.resources import files

    if name not in SCHEMA_NAMES:
        raise KeyError(f"no schema {name!r}; schemas: {', '.join(SCHEMA_NAMES)}")
    return json.loads(files("sim.schemas").joinpath(f"{name}.schema.json").read_text(encoding="utf-8"))


def run_document(result, exit_code: int) -> dict:
    """``hydroplant run --json``: the :class:`sim.run.runner.RunResult` of the run."""
    from sim.methods import Method

    s = result.scenario
    return {
        "command": "run",
        "status": result.status,
        "exit_code": exit_code,
        "scenario": str(s.path),
        "log": str(result.log_path),
        "method": Method(s.mode, s.coupling, bool(getattr(s, "pbd_blend", False))).name,
        "mode": s.mode,
        "coupling": s.coupling,
        "dt_s": s.dt,
        "duration_s": s.duration,
        "message": result.message,
        "simulated_time_s": result.simulated_time,
        "wall_time_s": result.wall_time,
        "steps": result.steps,
        "real_time_factor": result.real_time_factor,
        "final_strokes_m": dict(result.final_strokes),
        "final_joints": dict(result.final_joints),
        "peak_pressure_pa": dict(result.peak_pressure),
        "min_pressure_pa": dict(result.min_pressure),
        "pressure_extremes_every_step": bool(result.extremes_every_step),
        "energy_j": {k: v for k, v in result.energy.items() if k != "relative"},
        "energy_residual_relative": result.energy.get("relative"),
    }
