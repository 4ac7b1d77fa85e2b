"""A Foxglove WebSocket view of recorded messages: ``sappc replay BAG --live [PORT]``.

:class:`LiveServer` is a Foxglove WebSocket server (the Foxglove WebSocket protocol, which
``foxglove-sdk`` 0.30 serves as subprotocol ``foxglove.sdk.v1``, from its Rust core) whose
channels are a bag's: each advertised with the bag's topic, its message encoding (``cdr``) and its schema as recorded (name, ``ros2msg`` encoding and text), and
each message forwarded as its recorded bytes with its log time as the message's timestamp: nothing
is decoded or re-encoded.  It knows nothing of where the bytes come from, so that ``sappc run
--live`` feeds it from the recorder (:mod:`sappc.graph.recorder`); :func:`serve_bag` feeds it from a bag.

:func:`serve_bag` streams the bag a chunk at a time (:class:`~sappc.bag.mcap_scan.McapWalk`): memory
holds one chunk, whatever the bag's length (a 6 h bag has tens of millions of messages).  The
channels come from the file's summary section (its schemas and channels, read without the data
section, :func:`~sappc.bag.mcap_scan.summary_channels`); a bag cut short, which has none, is
walked once for its definitions first.  Each message
is sent at its log time from the first message, divided by ``rate``: a lockstep bag is logged on
simulated time (:mod:`sappc.graph.recorder`), so ``rate`` 1 shows the experiment at real-time pace;
one that cannot keep up sends as fast as it can (the largest lag is reported).  The server also
announces the bag's time (the protocol's ``time`` capability), which Foxglove's timeline follows.

Each client has a queue of :data:`MESSAGE_BACKLOG` messages: a client slower than the replay loses
the oldest (the SDK drops them), so a slow viewer costs no memory; playback never waits for it.
The server listens on 127.0.0.1 unless told otherwise: the view is unauthenticated and anyone who
reaches the port reads every message.
"""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import foxglove
import numpy as np
from foxglove.websocket import Capability, ChannelView, Client, ServerListener

from gnc_common.validation import ConfigError, check_positive

from sappc.bag.errors import BagError
from sappc.bag.mcap_scan import MAGIC, Channel, McapWalk, summary_channels

__all__ = ["DEFAULT_HOST", "DEFAULT_PORT", "LAYOUT_NAME", "MESSAGE_BACKLOG", "LiveServer", "bag_channels", "serve_bag", "write_layout",
           "ws_url"]

#: The port Foxglove's "Open connection" dialog proposes for a Foxglove WebSocket.
DEFAULT_PORT = 8765
#: Where the server listens unless told otherwise: this machine only (the view is unauthenticated).
DEFAULT_HOST = "127.0.0.1"
#: Messages queued per client before the oldest is dropped (the SDK's default is 1024; a 100 Hz
#: flight has about 25 topics, so this is a few seconds of a slow client at rate 1).
MESSAGE_BACKLOG = 8192
#: Longest sleep between checks while waiting (Ctrl-C is seen within it) [s].
_POLL_S = 0.05
#: How often the server announces the bag's time to clients [s of wall time].
_TIME_PERIOD_S = 0.05


def bag_channels(path: str | Path) -> dict[int, Channel]:
    """Every channel of the MCAP file at ``path``, by id, with its schema's text.

    Raises
    ------
    BagError
        If the file is not an MCAP file or has no channel.
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            if f.read(len(MAGIC)) != MAGIC:
                raise BagError(f"{path}: not an MCAP file (no MCAP magic at the start)")
        channels = summary_channels(path)
        if channels is None:  # a bag cut short: its definitions as a walk finds them, a chunk at a time
            walk = McapWalk(path)
            for _ in walk.pieces():
                pass
            channels = walk.channels
    except OSError as exc:
        raise BagError(f"{path}: cannot read ({exc.strerror})") from None
    except (ValueError, struct.error, UnicodeDecodeError) as exc:
        raise BagError(f"{path}: unreadable schema or channel record ({exc})") from None
    if not channels:
        raise BagError(f"{path}: no channel in the bag")
    return channels


#: The shipped Foxglove layout's name beside a bag (``sappc run``'s and ``sappc simulate --record``'s).
LAYOUT_NAME = "foxglove_layout.json"


def write_layout(bag_dir: str | Path) -> Path:
    """Copy the layout shipped with the package (``sappc/data/foxglove/sappc_layout.json``) into
    ``bag_dir`` as :data:`LAYOUT_NAME` (Foxglove: Layouts, Import from file); return its path."""
    from importlib import resources

    path = Path(bag_dir) / LAYOUT_NAME
    path.write_bytes((resources.files("sappc") / "data" / "foxglove" / "sappc_layout.json").read_bytes())
    return path


def ws_url(host: str, port: int) -> str:
    """The address a client connects to (an IPv6 host in brackets)."""
    return f"ws://[{host}]:{port}" if ":" in host else f"ws://{host}:{port}"


class _Subscriptions(ServerListener):
    """The server's listener: how many clients subscribe to each channel (called from the server's
    threads; the protocol's other callbacks do nothing)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.count: dict[int, int] = {}  # SDK channel id -> subscriptions

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        with self.lock:
            self.count[channel.id] = self.count.get(channel.id, 0) + 1

    def on_unsubscribe(self, client: Client, channel: ChannelView) -> None:  # also when a client disconnects
        with self.lock:
            self.count[channel.id] = max(self.count.get(channel.id, 0) - 1, 0)


class LiveServer:
    """A Foxglove WebSocket server advertising ``channels`` (see the module docstring); stop it with
    :meth:`close` (or use it as a context manager).

    Raises
    ------
    ConfigError
        If it cannot listen on ``host``:``port`` (the port taken, an unknown host).
    """

    def __init__(self, channels: Iterable[Channel], *, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
                 name: str = "sappc") -> None:
        if not 0 <= port <= 65535:
            raise ConfigError(f"--live: the port must be 0 to 65535, got {port}")
        self._context = foxglove.Context()  # its own: the SDK's global context and its channels are not touched
        self._subscriptions = _Subscriptions()
        try:
            self._server = foxglove.start_server(name=name, host=host, port=port, capabilities=[Capability.Time],
                                                 server_listener=self._subscriptions, context=self._context,
                                                 message_backlog_size=MESSAGE_BACKLOG)
        except Exception as exc:  # the SDK raises its own error type for a bind failure
            raise ConfigError(f"--live: cannot listen on {host}:{port} ({exc})") from None
        self.host = host
        self.port = self._server.port
        self.url = ws_url(host, self.port)
        self._channels: dict[int, Any] = {}  # bag channel id -> the SDK channel (foxglove.Channel.base)
        self._sdk_ids: dict[int, int] = {}  # bag channel id -> SDK channel id
        for ch in channels:
            schema = foxglove.Schema(name=ch.schema_name, encoding=ch.schema_encoding, data=ch.schema_data) if ch.schema_name else None
            channel = foxglove.Channel(ch.topic, schema=schema, message_encoding=ch.message_encoding, context=self._context)
            self._channels[ch.id] = channel.base  # BaseChannel.log: the bytes as given, no JSON handling
            self._sdk_ids[ch.id] = channel.id()
        self.closed = False

    def __enter__(self) -> LiveServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def log(self, channel_id: int, payload: bytes, log_time_ns: int) -> None:
        """Send ``payload`` on the bag's channel ``channel_id`` to its subscribers, stamped ``log_time_ns``."""
        channel = self._channels.get(channel_id)
        if channel is not None:
            channel.log(payload, log_time_ns)

    def broadcast_time(self, ns: int) -> None:
        """Announce the current time (of the bag, or of the run) to every client [ns]."""
        self._server.broadcast_time(int(ns))

    def subscriptions(self, channel_id: int) -> int:
        """How many clients subscribe to the bag's channel ``channel_id``."""
        with self._subscriptions.lock:
            return self._subscriptions.count.get(self._sdk_ids.get(channel_id, -1), 0)

    def any_subscription(self) -> bool:
        """Whether any client subscribes to anything (a client that disconnects unsubscribes)."""
        with self._subscriptions.lock:
            return any(self._subscriptions.count.values())

    def status(self, message: str, level: str = "info") -> None:
        """Show ``message`` to every client (Foxglove's problems list) at ``level`` (info, warning or error)."""
        from foxglove import StatusLevel

        levels = {"info": StatusLevel.Info, "warning": StatusLevel.Warning, "error": StatusLevel.Error}
        self._server.publish_status(message, levels[level])

    def close(self) -> None:
        """Stop serving: clients are disconnected, the port is closed."""
        if self.closed:
            return
        self.closed = True
        for channel in self._channels.values():
            channel.close()
        self._server.stop()


def _wait(until: Callable[[], bool], timeout_s: float) -> bool:
    """Poll ``until`` every :data:`_POLL_S` until it holds (True) or ``timeout_s`` has passed (False)."""
    end = time.monotonic() + timeout_s
    while not until():
        left = end - time.monotonic()
        if left <= 0:
            return False
        time.sleep(min(_POLL_S, left))
    return True


@dataclass
class _Pass:
    """What one pass over the bag sent."""

    messages: int = 0
    max_lag_s: float = 0.0
    truncated: str | None = None
    last_ns: int | None = None


def _play(server: LiveServer, path: Path, keep: set[int], rate: float) -> _Pass:
    """Send every message of ``keep``'s channels at its log time from the first one, divided by ``rate``."""
    done = _Pass()
    walk = McapWalk(path)
    first_ns: int | None = None
    t0 = 0.0
    next_time = 0.0
    keep_ids = np.fromiter(keep, dtype=np.int64)
    for piece in walk.pieces():
        sel = np.flatnonzero(np.isin(piece.channel_id, keep_ids))
        if sel.size == 0:
            continue
        if first_ns is None:
            first_ns, t0 = int(piece.log_time_ns[sel[0]]), time.monotonic()
        data = piece.data
        due = t0 + (piece.log_time_ns[sel] - first_ns) / 1e9 / rate
        for cid, log_ns, start, length, at in zip(piece.channel_id[sel].tolist(), piece.log_time_ns[sel].tolist(),
                                                  piece.start[sel].tolist(), piece.length[sel].tolist(), due.tolist()):
            now = time.monotonic()
            while now < at:
                time.sleep(min(at - now, _POLL_S))
                now = time.monotonic()
            done.max_lag_s = max(done.max_lag_s, now - at)
            server.log(cid, data[start : start + length], log_ns)
            done.messages += 1
            if now >= next_time:
                server.broadcast_time(log_ns)
                next_time = now + _TIME_PERIOD_S
            done.last_ns = log_ns
    if done.last_ns is not None:
        server.broadcast_time(done.last_ns)
    done.truncated = walk.truncated
    return done


def _say_now(line: str) -> None:
    """:func:`serve_bag`'s lines on stdout, each at once even into a pipe (a client waits for the address)."""
    print(line, flush=True)


def serve_bag(path: str | Path, *, rate: float = 1.0, topics: list[str] | None = None, loop: bool = False,
              wait_subscribers: int = 0, start_delay_s: float = 0.0, linger_s: float = 2.0, host: str = DEFAULT_HOST,
              port: int = DEFAULT_PORT, say: Callable[[str], object] | None = None) -> int:
    """Serve the bag at ``path`` to Foxglove clients (see the module docstring); return the exit status (0).

    Playback starts ``start_delay_s`` after the server does, once every served topic has
    ``wait_subscribers`` subscriptions; after the last message the server stays up until no client
    subscribes to anything, at most ``linger_s``, so that clients receive what is queued for them.
    Ctrl-C stops the server and propagates (the command's exit status 130).  ``say``: where its
    lines go (default: stdout, each flushed at once).

    Raises
    ------
    BagError
        If the bag is not readable, or ``topics`` names a topic it does not have.
    ConfigError
        For a bad value, or when the server cannot listen.
    """
    from sappc.bag.read import mcap_file

    say = _say_now if say is None else say
    rate = check_positive("--rate", rate)
    if wait_subscribers < 0:
        raise ConfigError(f"--wait-subscribers must be >= 0, got {wait_subscribers}")
    start_delay_s = check_positive("--start-delay", start_delay_s, allow_zero=True)
    linger_s = check_positive("--linger", linger_s, allow_zero=True)
    if not 0 <= port <= 65535:
        raise ConfigError(f"--live: the port must be 0 to 65535, got {port}")
    file = mcap_file(Path(path))
    channels = bag_channels(file)
    if topics:
        wanted = {t.lstrip("/") for t in topics}
        have = {c.topic.lstrip("/") for c in channels.values()}
        unknown = sorted(wanted - have)
        if unknown:
            raise BagError(f"{path}: no topic {unknown[0]!r} in the bag; it has {sorted(c.topic for c in channels.values())}")
        channels = {cid: c for cid, c in channels.items() if c.topic.lstrip("/") in wanted}
    with LiveServer(channels.values(), host=host, port=port) as server:
        say(f"serving {len(channels)} topics of {path} to Foxglove at {server.url} (Foxglove: Open connection, "
            f"Foxglove WebSocket) at rate {rate:g}" + (", looping" if loop else "") + "; Ctrl-C stops")
        if wait_subscribers:
            say(f"waiting for {wait_subscribers} subscriber(s) on every served topic")
        started = time.monotonic()
        _wait(lambda: time.monotonic() - started >= start_delay_s
              and all(server.subscriptions(cid) >= wait_subscribers for cid in channels), float("inf"))
        passes, sent, max_lag_s = 0, 0, 0.0
        while True:
            done = _play(server, file, set(channels), rate)
            passes, sent, max_lag_s = passes + 1, sent + done.messages, max(max_lag_s, done.max_lag_s)
            if done.truncated:
                say(f"the bag ends early: {done.truncated}")
            if not loop or done.messages == 0:
                break
        server.status("sappc replay: the end of the bag")
        say(f"sent {sent} messages ({passes} pass(es)); largest lag behind schedule {max_lag_s * 1e3:.1f} ms")
        _wait(lambda: not server.any_subscription(), linger_s)
    return 0
