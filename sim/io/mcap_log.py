"""MCAP logging of simulation runs, in one import: ROS 2 CDR for the numeric topics, JSON for the irregular ones.

Every log is read by Foxglove natively: CDR channels (schema encoding ``ros2msg``, message
encoding ``cdr``) carry the numeric, fixed-layout topics; JSON channels with JSON Schema carry
irregular messages (events, the scene update).  The parts live in their own modules and are
re-exported here:

- :mod:`sim.io.log_schemas`: message types, CDR and JSON encodings, log times;
- :mod:`sim.io.log_writer`: :class:`LogWriter`, :class:`Channel`, :class:`Frame` (batched
  records, output safety);
- :mod:`sim.io.mcap_file`: the MCAP file itself on the public ``mcap.records`` API (chunked
  writer with one compression thread, damage-tolerant scanner);
- :mod:`sim.io.log_reader`: :func:`read_log`, :func:`inspect_log`, :func:`log_summary`, :func:`merge_logs`;
- :mod:`sim.io.log_export`: a log's topics as CSV files or one HDF5 file (not re-exported: h5py is optional);
- :mod:`sim.io.log_recover`: :func:`verify_log` and :func:`recover`.

Conventions:

- ``log_time = publish_time`` is *simulation* time in integer nanoseconds computed from
  the integer step index, never from an accumulated float time (:func:`step_log_time`).
- Every sample carries a ``timestamp`` equal to its log time (``{sec, nanosec}`` in CDR,
  ``{sec, nsec}`` in JSON).
- NaN and ±inf are stored as they are in CDR (float64); JSON is strict: non-finite floats
  are written as ``null`` and read back as NaN.
- The file is written to ``PATH.partial``, created exclusively (two writers never share
  it; an existing one is never replaced unless asked), and published as ``PATH`` when it
  is finished, also when the ``with`` block raises; an existing ``PATH`` is replaced only
  with ``overwrite=True``. A file cut by SIGKILL or damaged can be rebuilt with
  :func:`recover`, which skips damaged chunks and keeps the others.

This package does not import MuJoCo; see :mod:`sim.io.foxglove_scene` for the model-specific
channels.

Example::

    with LogWriter("run.mcap", dt=1e-3, run_metadata={"scene": "demo"}) as log:
        pump = log.cdr_channel("/pump", flat_schema("t_msgs/msg/Pump", {"p_pa": "p [Pa]"}), fields=["p_pa"])
        for step in range(1000):
            pump.append(step, (2e7,))
    assert read_log("run.mcap").topic("/pump")["p_pa"].size == 1000
"""

from sim.io.log_reader import RunLog, TopicData, inspect_log, log_info, log_summary, merge_logs, read_log
from sim.io.log_recover import RecoverReport, recover, verify_log
from sim.io.log_schemas import (FOXGLOVE_SCHEMAS, FRAME_TRANSFORMS, JOINT_STATES, TIME, TIMESTAMP, Column, LogLevel,
                                MsgField, MsgType, cdr_decode, cdr_encode, flat_schema, log_message, log_schema,
                                ros2msg_type, scene_update_schema, step_log_time, to_json_bytes)
from sim.io.log_writer import Attachment, Channel, Frame, JointStatesChannel, LogWriter
from sim.io.mcap_file import RESULT_METADATA, RUN_METADATA, LogPathError, LogReadError, RunStatus, library_string

__all__ = [
    "Attachment",
    "Channel",
    "Column",
    "FOXGLOVE_SCHEMAS",
    "FRAME_TRANSFORMS",
    "Frame",
    "JOINT_STATES",
    "JointStatesChannel",
    "LogLevel",
    "LogPathError",
    "LogReadError",
    "LogWriter",
    "MsgField",
    "MsgType",
    "RecoverReport",
    "RESULT_METADATA",
    "RUN_METADATA",
    "RunLog",
    "RunStatus",
    "TIME",
    "TIMESTAMP",
    "TopicData",
    "cdr_decode",
    "cdr_encode",
    "flat_schema",
    "inspect_log",
    "library_string",
    "log_info",
    "log_message",
    "log_schema",
    "log_summary",
    "merge_logs",
    "read_log",
    "recover",
    "ros2msg_type",
    "scene_update_schema",
    "step_log_time",
    "to_json_bytes",
    "verify_log",
]
