"""A live Foxglove stream of a run's log topics, and operator commands published by a Foxglove client.

:class:`FoxgloveLive` serves a Foxglove WebSocket (``foxglove-sdk``, optional extra ``live``) and
is three things at once:

- a :class:`~sim.io.log_writer.LogTee` of the run's :class:`~sim.io.log_writer.LogWriter`
  (:meth:`FoxgloveLive.attach`): every log channel is advertised with the log's own schema
  (name, encoding, text) and message encoding, and every message is published with the bytes
  and log time it has in the file, as the writer drains them (a paced loop calls
  ``log.drain()`` once per frame).  A client sees the topics it would see in the finished
  MCAP, while the run goes on; JSON channels (the scene, the events) keep their last message,
  sent again when a client subscribes, so a late client still gets the static scene;
- a :class:`~sim.live.protocol.FrameSink` (:meth:`FoxgloveLive.show`): the server time follows
  the simulated time, and the frame timing goes out on ``/hydroplant/frame``
  (:mod:`sim.live.frame_topic`) unless the log already has that topic;
- the owner of a :class:`FoxgloveCommands` (:attr:`FoxgloveLive.commands`), the
  :class:`~sim.live.protocol.CommandSource` of a Foxglove client publishing JSON objects
  (``{"boom_valve": 0.4}``, a Publish panel, a teleop or joystick panel) on
  ``/hydroplant/commands``; the server advertises the ``clientPublish`` capability.

Each log channel is advertised once per server, when the log registers it (or when the server
is attached, for the channels registered before).  A client connected while a channel is
advertised may have a subscription it sends at once rejected (error status ``Unknown channel
ID``): foxglove-sdk's server queues the advertisement to the client before it records the
channel as advertised to that client.  The channel stays advertised; subscribing again
succeeds.  Channels that exist when a client connects are recorded before the server reads
anything from it.

The server binds to ``127.0.0.1`` by default: only this machine can connect (there is no
authentication; bind to another address only on a trusted network).  Slow clients lose the
oldest messages first (``message_backlog_size``, 1024 per client by default), never the run.

Example
-------
::

    live = FoxgloveLive(port=8765)          # open ws://127.0.0.1:8765 in Foxglove
    live.attach(log)                        # before the first drain of the log
    ...                                     # per frame: step, push the samples, then
    log.drain(); live.show(t, qpos, values, stats)
    commands = live.commands.poll(t)        # what the client published last
    live.close()
"""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sim.io.log_schemas import cdr_encode
from sim.io.log_writer import ChannelInfo, LogTee, LogWriter
from sim.live.frame_topic import FRAME_FIELDS, FRAME_STATS, FRAME_TOPIC, frame_row
from sim.live.protocol import FrameStats

COMMAND_TOPIC = "/hydroplant/commands"
DEFAULT_PORT = 8765  # Foxglove's default WebSocket port


def _foxglove():
    try:
        import foxglove
        import foxglove.websocket  # noqa: F401 - the server classes
    except ImportError as error:  # pragma: no cover - the optional extra
        raise ImportError("the live Foxglove stream needs foxglove-sdk: pip install 'hydroplant[live]'") from error
    return foxglove


def flatten_command(message: Any, prefix: str = "") -> dict[str, float]:
    """The numbers of a decoded JSON command as ``{name: value}``; nested objects and arrays give dotted names.

    ``{"boom_valve": 0.4}`` → ``{"boom_valve": 0.4}``; a teleop panel's twist
    ``{"linear": {"x": 1}}`` → ``{"linear.x": 1.0}``; a joystick's ``{"axes": [0.1, -1]}`` →
    ``{"axes.0": 0.1, "axes.1": -1.0}``.  Booleans, strings and non-finite numbers are left out.
    """
    out: dict[str, float] = {}
    if isinstance(message, Mapping):
        items = ((str(k), v) for k, v in message.items())
    elif isinstance(message, list):
        items = ((str(i), v) for i, v in enumerate(message))
    else:
        return out
    for key, value in items:
        name = f"{prefix}.{key}" if prefix else key
        if isinstance(value, bool):
            continue
        if isinstance(value, (int, float)):
            if math.isfinite(value):
                out[name] = float(value)
        else:
            out.update(flatten_command(value, name))
    return out


class FoxgloveCommands:
    """:class:`~sim.live.protocol.CommandSource` of the JSON objects Foxglove clients publish on ``topic``.

    :meth:`poll` returns the latest value of every name any client has published (numbers of
    the JSON object, see :func:`flatten_command`).  When the publishing channel goes away
    (the client unadvertises or disconnects) every name it published drops to 0.0: the
    machine's valves return to neutral when the operator leaves.  A message that is not a
    JSON object is ignored.  Thread-safe: the server calls in from its own thread.

    It is also the server's listener (the ``foxglove.websocket.ServerListener`` callbacks it
    needs); :class:`FoxgloveLive` owns one.
    """

    def __init__(self, topic: str = COMMAND_TOPIC):
        self.topic = topic
        self._lock = threading.Lock()
        self._values: dict[str, float] = {}
        self._channels: dict[tuple[int, int], set[str]] = {}  # (client id, client channel id) -> names published
        self.received = 0
        """Messages accepted so far."""
        self.subscriptions = 0
        """Subscriptions made by clients so far (to any channel)."""
        self._on_subscribe: list = []

    # -- CommandSource --------------------------------------------------------------
    def poll(self, t: float) -> dict[str, float]:
        """The latest commanded values (name → value)."""
        with self._lock:
            return dict(self._values)

    def close(self) -> None:
        """Nothing to release (the server is closed by its owner)."""

    # -- server listener ------------------------------------------------------------
    def on_client_advertise(self, client: Any, channel: Any) -> None:
        if channel.topic == self.topic and channel.encoding == "json":
            with self._lock:
                self._channels.setdefault((client.id, channel.id), set())

    def on_client_unadvertise(self, client: Any, client_channel_id: int) -> None:
        with self._lock:
            names = self._channels.pop((client.id, client_channel_id), set())
            for name in names:
                self._values[name] = 0.0

    def on_message_data(self, client: Any, client_channel_id: int, data: bytes) -> None:
        key = (client.id, client_channel_id)
        with self._lock:
            if key not in self._channels:
                return
        try:
            message = json.loads(bytes(data))
        except ValueError:
            return
        if not isinstance(message, dict):
            return
        values = flatten_command(message)
        with self._lock:
            names = self._channels.get(key)
            if names is None:  # unadvertised meanwhile
                return
            names.update(values)
            self._values.update(values)
            self.received += 1

    def on_subscribe(self, client: Any, channel: Any) -> None:
        with self._lock:
            self.subscriptions += 1
        for hook in self._on_subscribe:
            hook(channel.id)

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        return None


class FoxgloveLive(LogTee):
    """Foxglove WebSocket server streaming a run's log live; see the module docstring.

    Parameters
    ----------
    host : str, optional
        Address to bind (``127.0.0.1``: this machine only).
    port : int, optional
        TCP port (Foxglove's default 8765; 0 picks a free one, see :attr:`port`).
    name : str, optional
        Server name shown by Foxglove.
    command_topic : str, optional
        Topic clients publish commands on.

    Attributes
    ----------
    commands : FoxgloveCommands
        The command source fed by clients.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT, *, name: str = "hydroplant",
                 command_topic: str = COMMAND_TOPIC):
        foxglove = _foxglove()
        from foxglove.websocket import Capability

        self._fx = foxglove
        self._context = foxglove.Context()
        self.commands = FoxgloveCommands(command_topic)
        self._lock = threading.Lock()
        self._infos: dict[int, ChannelInfo] = {}  # log channel id -> the channel streamed under it
        self._channels: dict[int, Any] = {}  # log channel id -> foxglove Channel
        self._by_fox_id: dict[int, int] = {}  # foxglove channel id -> log channel id
        self._latched: dict[int, tuple[bytes, int]] = {}  # log channel id -> last JSON message and its log time
        self._resend: set[int] = set()  # log channel ids whose latched message goes out again
        self._topics: set[str] = set()
        self._frame_channel: Any = None
        self._last_time = 0
        self.commands._on_subscribe.append(self._subscribed)
        self.server = foxglove.start_server(
            name=name, host=host, port=int(port), context=self._context, server_listener=self.commands,
            capabilities=[Capability.ClientPublish, Capability.Time], supported_encodings=["json"])
        self._closed = False

    @property
    def port(self) -> int:
        """The TCP port the server listens on."""
        return self.server.port

    def attach(self, log: LogWriter) -> None:
        """Stream ``log``'s topics (call before the log's first drain so nothing written is missed)."""
        log.add_tee(self)

    # -- LogTee ---------------------------------------------------------------------
    def channel(self, info: ChannelInfo) -> None:
        """Advertise log channel ``info`` (once: the same channel handed over again is already streamed)."""
        with self._lock:
            known = self._infos.get(info.id)
        if known is not None:
            if known != info:
                raise ValueError(f"log channel {info.id} ({info.topic!r}) is already streamed as {known.topic!r}")
            return
        schema = self._fx.Schema(name=info.schema_name, encoding=info.schema_encoding, data=bytes(info.schema_data))
        channel = self._fx.Channel(info.topic, schema=schema, message_encoding=info.message_encoding,
                                   context=self._context, metadata=dict(info.metadata))
        with self._lock:
            self._infos[info.id] = info
            self._channels[info.id] = channel
            self._by_fox_id[channel.id()] = info.id
            self._topics.add(info.topic)
            if info.message_encoding == "json":
                self._latched[info.id] = (b"", -1)

    def messages(self, records: Sequence[tuple[int, int, bytes]]) -> None:
        if self._closed:
            return
        self._send_latched()
        channels, latched = self._channels, self._latched
        for channel_id, log_time, data in records:
            channel = channels.get(channel_id)
            if channel is None:
                continue
            channel.log(data, log_time=log_time)
            if channel_id in latched:
                latched[channel_id] = (data, log_time)
            self._last_time = max(self._last_time, log_time)

    def _subscribed(self, fox_id: int) -> None:
        with self._lock:
            log_id = self._by_fox_id.get(fox_id)
            if log_id is not None and log_id in self._latched:
                self._resend.add(log_id)

    def _send_latched(self) -> None:
        with self._lock:
            resend, self._resend = self._resend, set()
        for log_id in resend:
            data, log_time = self._latched[log_id]
            if log_time >= 0:
                self._channels[log_id].log(data, log_time=log_time)

    # -- FrameSink ------------------------------------------------------------------
    def show(self, t: float, qpos: np.ndarray, values: Mapping[str, float], stats: FrameStats) -> None:
        """Advance the clients' clock to ``t`` and publish the frame timing (unless the log carries it)."""
        if self._closed:
            return
        self._send_latched()
        log_time = max(self._last_time, round(t * 1e9))
        if FRAME_TOPIC not in self._topics:
            if self._frame_channel is None:
                schema = self._fx.Schema(name=FRAME_STATS.name, encoding="ros2msg", data=FRAME_STATS.definition().encode())
                self._frame_channel = self._fx.Channel(FRAME_TOPIC, schema=schema, message_encoding="cdr",
                                                       context=self._context)
            sec, nsec = divmod(log_time, 1_000_000_000)
            message = {"timestamp": {"sec": sec, "nanosec": nsec}, **dict(zip(FRAME_FIELDS, frame_row(stats)))}
            self._frame_channel.log(cdr_encode(FRAME_STATS, message), log_time=log_time)
        self.server.broadcast_time(log_time)

    def close(self) -> None:
        """Stop the server (idempotent)."""
        if not self._closed:
            self._closed = True
            self.server.stop()


__all__ = ["COMMAND_TOPIC", "DEFAULT_PORT", "FoxgloveCommands", "FoxgloveLive", "flatten_command"]
