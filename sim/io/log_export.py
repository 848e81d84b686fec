"""A log's topics as CSV files or one HDF5 file (``hydroplant log export``).

The topics are read through :func:`sim.io.log_reader.read_log`, so the exported columns are its numpy
columns value for value:

* **CSV** (:func:`export_csv`): one file per topic, named after the topic (``/hydroplant/cylinders/boom_cyl``
  → ``hydroplant.cylinders.boom_cyl.csv``), a header row, then one row per message: ``t`` (log time [s],
  the simulation time) and every numeric field (``p_cap_pa``, ``position/boom_hinge`` …; the suffix names
  the SI unit), then the text fields.  Numbers are written in Python's shortest round-trip form
  (``repr``), so reading them back gives the same float64 bit for bit; NaN is ``nan``.
* **HDF5** (:func:`export_hdf5`, needs `h5py <https://www.h5py.org>`_, ``pip install 'hydroplant[hdf5]'``):
  one group per topic at the topic's path (``/hydroplant/cylinders/boom_cyl``) with the attributes
  ``topic`` and ``schema``, a float64 dataset ``t`` [s] and one dataset per field (float64, or UTF-8
  strings for text fields; a field ``position/boom_hinge`` is the dataset ``boom_hinge`` of the
  subgroup ``position``).  The file's attributes carry the log's metadata records as
  ``<record>.<key>`` (``hydroplant.run.dt_s`` …) and ``source`` (the log's file name).

By default every topic is exported except the 3D scene (``foxglove.SceneUpdate``: geometry, not a
signal); ``topics`` names others.  No existing file is replaced unless ``overwrite=True``, and the
log itself never (:func:`sim.io.files.check_output`).

Example::

    from sim.io.log_export import export_log
    report = export_log("logs/lift.mcap", "csv")      # logs/lift-csv/*.csv
    report["files"]
"""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np

from hydraulics.components import CircuitError

from sim.io.files import check_output
from sim.io.log_reader import RunLog, read_log

__all__ = ["FORMATS", "SKIPPED_SCHEMAS", "csv_name", "default_output", "export_csv", "export_hdf5", "export_log"]

FORMATS = ("csv", "hdf5")
SKIPPED_SCHEMAS = ("foxglove.SceneUpdate",)  # not exported unless named
TIME_COLUMN = "t"


def csv_name(topic: str) -> str:
    """The CSV file name of a topic: ``/hydroplant/cylinders/boom_cyl`` → ``hydroplant.cylinders.boom_cyl.csv``."""
    return topic.strip("/").replace("/", ".") + ".csv"


def default_output(log_path, fmt: str) -> Path:
    """Beside the log: ``<name>-csv/`` (CSV) or ``<name>.h5`` (HDF5), ``<name>`` the log's without ``.mcap``."""
    log_path = Path(log_path)
    stem = log_path.name.removesuffix(".mcap")
    return log_path.with_name(stem + "-csv") if fmt == "csv" else log_path.with_name(stem + ".h5")


def _topics(log: RunLog, topics) -> list[str]:
    if topics:
        unknown = [t for t in topics if t not in log]
        if unknown:
            raise CircuitError(f"{log.path}: no topic {unknown[0]!r}; topics: {', '.join(log.topics)}")
        return list(dict.fromkeys(topics))
    return [t for t in log.topics if log.schema_names[t] not in SKIPPED_SCHEMAS and log.message_counts[t] > 0]


def _number(value: float) -> str:
    return repr(float(value))


def export_csv(log: RunLog, out_dir, topics=None, *, overwrite: bool = False) -> list[dict]:
    """One CSV file per topic into ``out_dir`` (created if needed); see the module docstring.

    Every file is checked before any is written: an existing one is refused unless ``overwrite``
    (:class:`CircuitError` naming it).  Returns per topic ``{"topic", "file", "rows", "columns"}``.
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise CircuitError(f"{out_dir}: not a folder; CSV export writes one file per topic into a folder")
    names = {}
    for topic in _topics(log, topics):
        name = csv_name(topic)
        if name in names.values():
            raise CircuitError(f"{log.path}: topics {topic!r} and another both map to the file name {name!r}")
        names[topic] = name
    paths = {topic: out_dir / name for topic, name in names.items()}
    if out_dir.is_dir():
        for path in paths.values():
            check_output(path, [log.path], overwrite=overwrite, what="CSV file")
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for topic, path in paths.items():
        data = log.topic(topic)
        columns = [TIME_COLUMN] + data.fields + data.text_fields
        numeric = [data.t] + [data[f] for f in data.fields]
        text = [data.text(f) for f in data.text_fields]
        with open(path, "w" if overwrite else "x", newline="", encoding="utf-8") as f:
            writer = csv.writer(f)
            writer.writerow(columns)
            for i in range(len(data)):
                writer.writerow([_number(col[i]) for col in numeric] + ["" if col[i] is None else col[i] for col in text])
        written.append({"topic": topic, "file": str(path), "rows": len(data), "columns": columns})
    return written


def export_hdf5(log: RunLog, out_file, topics=None, *, overwrite: bool = False) -> list[dict]:
    """Every topic as a group of ``out_file``; see the module docstring.  Needs h5py (``CircuitError`` naming the
    extra otherwise).  Returns per topic ``{"topic", "group", "rows", "columns"}``."""
    try:
        import h5py
    except ImportError:
        raise CircuitError("HDF5 export needs h5py: pip install 'hydroplant[hdf5]' (or use --format csv)") from None
    chosen = _topics(log, topics)
    out_file = check_output(Path(out_file), [log.path], overwrite=overwrite, what="HDF5 file")
    written = []
    with h5py.File(out_file, "w" if overwrite else "x") as f:
        f.attrs["source"] = log.path.name
        for record, values in log.metadata.items():
            for key, value in values.items():
                f.attrs[f"{record}.{key}"] = value
        for topic in chosen:
            data = log.topic(topic)
            group_name = topic.strip("/") or "root"
            if group_name in f:
                raise CircuitError(f"{log.path}: topic {topic!r} collides with another topic's group or field in HDF5")
            group = f.create_group(group_name)
            group.attrs["topic"] = topic
            group.attrs["schema"] = log.schema_names[topic]
            group.create_dataset(TIME_COLUMN, data=np.asarray(data.t, dtype=np.float64))
            for name in data.fields:
                if name == TIME_COLUMN or name in group:
                    raise CircuitError(f"{log.path}: field {name!r} of topic {topic!r} collides with another dataset")
                group.create_dataset(name, data=np.asarray(data[name], dtype=np.float64))
            for name in data.text_fields:
                if name == TIME_COLUMN or name in group:
                    raise CircuitError(f"{log.path}: field {name!r} of topic {topic!r} collides with another dataset")
                values = ["" if v is None else str(v) for v in data.text(name)]
                group.create_dataset(name, data=values, dtype=h5py.string_dtype())
            written.append({"topic": topic, "group": "/" + group_name, "rows": len(data),
                            "columns": [TIME_COLUMN] + data.fields + data.text_fields})
    return written


def export_log(log_path, fmt: str, *, out=None, topics=None, overwrite: bool = False) -> dict:
    """Export a finished log as ``fmt`` (``"csv"`` or ``"hdf5"``) to ``out`` (default :func:`default_output`).

    Returns ``{"format", "log", "out", "files", "topics"}`` (``topics``: what :func:`export_csv` or
    :func:`export_hdf5` returns).  Bad input (not a log, an unknown topic, an existing output without
    ``overwrite``, h5py missing for HDF5) raises :class:`CircuitError` naming it.
    """
    if fmt not in FORMATS:
        raise CircuitError(f"--format: {fmt!r} is not one of {', '.join(FORMATS)}")
    log = read_log(log_path)
    out = Path(out) if out is not None else default_output(log_path, fmt)
    if os.path.lexists(out) and Path(out).resolve() == Path(log_path).resolve():
        raise CircuitError(f"{out}: is the log being exported; name another output")
    if fmt == "csv":
        rows = export_csv(log, out, topics, overwrite=overwrite)
        files = [r["file"] for r in rows]
    else:
        rows = export_hdf5(log, out, topics, overwrite=overwrite)
        files = [str(out)]
    return {"format": fmt, "log": str(log_path), "out": str(out), "files": files, "topics": rows}
