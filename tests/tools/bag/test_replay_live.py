"""``sappc replay BAG --live [PORT]`` (issue 51, item 3): a recorded bag served to Foxglove over the
Foxglove WebSocket protocol by :mod:`sappc.bag.live`, checked with a client of the protocol
(``websockets``, subprotocol ``foxglove.sdk.v1``: foxglove-sdk's name for ``foxglove.websocket.v1``,
the same messages; the SDK refuses the old name).

- the advertised channels are the bag's, each with its topic, ``cdr`` and its ``ros2msg`` schema as
  recorded (read back with the ``mcap`` package, not the project's reader);
- a client subscribed to every channel receives every message of the bag, per channel in the bag's
  order, each payload the recorded bytes and its timestamp the log time;
- the server is gone (the port refuses connections) when the replay ends, by itself or by Ctrl-C
  (exit status 130, one line);
- bad options get one line and exit status 2.

Every server is a ``sappc replay`` process on a port the system picks (``--live 0``; the address is
read from the line it prints), killed at the end of its test if still running.  Waits are on events
(a line, a message, the process's exit) with generous timeouts, never on fixed sleeps: a test that
needs every message starts the replay only once it has subscribed (``--wait-subscribers 1``), and
the bag's 2211 messages fit in the server's queue for a client (8192), so none is dropped however
slowly the client reads.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from sappc.bag.live import MESSAGE_BACKLOG

from conftest import ROOT

websockets = pytest.importorskip("websockets")

#: The subprotocol foxglove-sdk serves the Foxglove WebSocket protocol under.
SUBPROTOCOL = "foxglove.sdk.v1"
#: Generous bounds for what takes well under a second on an idle machine [s].
TIMEOUT_S = 120.0


def _mcap(bag: Path) -> Path:
    return next(bag.glob("*.mcap"))


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Experiment 1 for 2 s (201 samples, 11 topics, 2211 messages), recorded by ``sappc simulate --record``."""
    out = tmp_path_factory.mktemp("live") / "bag"
    proc = subprocess.run([sys.executable, "-m", "sappc", "simulate", "paper_tracking", "--duration", "2", "--record", str(out),
                           "--no-progress"], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert out.is_dir(), proc.stderr  # the run's verdict (a 2 s run settles nowhere) is not the point
    return out


@pytest.fixture(scope="module")
def recorded(bag: Path) -> dict[str, Any]:
    """The bag as the ``mcap`` package reads it: channels with their schemas, messages in file order."""
    from mcap.reader import make_reader

    with open(_mcap(bag), "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        channels = {c.topic: {"encoding": c.message_encoding, "schemaName": summary.schemas[c.schema_id].name,
                              "schemaEncoding": summary.schemas[c.schema_id].encoding,
                              "schema": summary.schemas[c.schema_id].data.decode()} for c in summary.channels.values()}
        messages: dict[str, list[tuple[int, bytes]]] = {t: [] for t in channels}
        for _schema, channel, message in reader.iter_messages(log_time_order=False):
            messages[channel.topic].append((message.log_time, bytes(message.data)))
    return {"channels": channels, "messages": messages, "count": sum(len(m) for m in messages.values())}


class Server:
    """A ``sappc replay BAG --live 0 ...`` process and the address it printed."""

    def __init__(self, bag: Path, *args: str) -> None:
        self.proc = subprocess.Popen([sys.executable, "-m", "sappc", "replay", str(bag), "--live", "0", *args], cwd=ROOT,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.lines: list[str] = []
        self.url = ""
        found = threading.Event()

        def read() -> None:
            assert self.proc.stdout is not None
            for line in self.proc.stdout:
                self.lines.append(line)
                if not found.is_set() and "ws://" in line:
                    self.url = re.search(r"ws://\S+", line).group(0)  # type: ignore[union-attr]
                    found.set()
            found.set()

        self.reader = threading.Thread(target=read, daemon=True)
        self.reader.start()
        assert found.wait(TIMEOUT_S) and self.url, f"no address printed: {self.lines} {self._stderr()}"
        self.port = int(self.url.rsplit(":", 1)[1])

    def _stderr(self) -> str:
        if self.proc.poll() is None:
            return ""
        assert self.proc.stderr is not None
        return self.proc.stderr.read()

    def wait(self) -> tuple[int, str, str]:
        """Wait for the process's end: (exit status, stdout, stderr)."""
        rc = self.proc.wait(TIMEOUT_S)
        self.reader.join(TIMEOUT_S)
        return rc, "".join(self.lines), self._stderr()

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(TIMEOUT_S)


@pytest.fixture
def serve() -> Iterator[Any]:
    """Start servers; each is killed at the end of the test if it is still running."""
    started: list[Server] = []

    def start(bag: Path, *args: str) -> Server:
        started.append(Server(bag, *args))
        return started[-1]

    yield start
    for s in started:
        s.kill()


def _refused(port: int) -> bool:
    """Whether nothing listens on 127.0.0.1:``port``."""
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) != 0


async def _advertised(ws: Any, n: int) -> dict[int, dict[str, Any]]:
    """Read the server's JSON messages until ``n`` channels are advertised: {channel id: channel}."""
    channels: dict[int, dict[str, Any]] = {}
    while len(channels) < n:
        message = await asyncio.wait_for(ws.recv(), TIMEOUT_S)
        if isinstance(message, str):
            data = json.loads(message)
            if data["op"] == "advertise":
                channels.update({c["id"]: c for c in data["channels"]})
    return channels


def _connect(url: str) -> Any:
    return websockets.connect(url, subprotocols=[SUBPROTOCOL], max_size=None, open_timeout=TIMEOUT_S)


def test_the_advertised_channels_are_the_bags_with_their_schemas_and_ctrl_c_ends_it(bag: Path, recorded: dict[str, Any], serve: Any) -> None:
    server = serve(bag, "--wait-subscribers", "1")  # nothing subscribes: it waits until Ctrl-C

    async def client() -> tuple[str | None, dict[str, Any], dict[int, dict[str, Any]]]:
        async with _connect(server.url) as ws:
            info = json.loads(await asyncio.wait_for(ws.recv(), TIMEOUT_S))
            return ws.subprotocol, info, await _advertised(ws, len(recorded["channels"]))

    protocol, info, channels = asyncio.run(client())
    assert protocol == SUBPROTOCOL
    assert info["op"] == "serverInfo" and "time" in info["capabilities"]
    by_topic = {c["topic"]: {k: c[k] for k in ("encoding", "schemaName", "schemaEncoding", "schema")} for c in channels.values()}
    assert len(by_topic) == len(channels)
    assert by_topic == recorded["channels"]
    assert all(c["encoding"] == "cdr" and c["schemaEncoding"] == "ros2msg" for c in by_topic.values())
    server.proc.send_signal(signal.SIGINT)
    rc, _out, err = server.wait()
    assert rc == 130, err
    assert err.strip().splitlines()[-1] == "sappc: interrupted", err
    assert _refused(server.port)


def test_a_subscription_receives_every_message_as_recorded_and_the_server_ends_with_the_bag(
        bag: Path, recorded: dict[str, Any], serve: Any) -> None:
    assert recorded["count"] <= MESSAGE_BACKLOG  # none can be dropped, however slowly this client reads
    server = serve(bag, "--wait-subscribers", "1", "--rate", "4", "--linger", str(TIMEOUT_S))

    async def client() -> tuple[dict[int, dict[str, Any]], dict[int, list[tuple[int, bytes]]]]:
        async with _connect(server.url) as ws:
            channels = await _advertised(ws, len(recorded["channels"]))
            subs = dict(enumerate(channels))  # subscription id -> channel id
            await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": s, "channelId": c} for s, c in subs.items()]}))
            got: dict[int, list[tuple[int, bytes]]] = {c: [] for c in channels}
            n = 0
            while n < recorded["count"]:
                message = await asyncio.wait_for(ws.recv(), TIMEOUT_S)
                if isinstance(message, bytes) and message[0] == 0x01:  # message data: opcode, subscription id u32, timestamp u64, payload
                    sub, stamp = int.from_bytes(message[1:5], "little"), int.from_bytes(message[5:13], "little")
                    got[subs[sub]].append((stamp, message[13:]))
                    n += 1
            return channels, got  # leaving: the client disconnects, and the lingering server ends

    channels, got = asyncio.run(client())
    for cid, messages in got.items():
        topic = channels[cid]["topic"]
        assert messages == recorded["messages"][topic], topic
    rc, out, err = server.wait()
    assert rc == 0, err
    assert f"sent {recorded['count']} messages (1 pass(es))" in out
    assert _refused(server.port)


def test_a_topic_list_serves_only_those_topics(bag: Path, serve: Any) -> None:
    # --wait-subscribers: the bag is played only once this client has subscribed, so the server
    # cannot have played it (50 times its speed: 40 ms) and closed before the client connects;
    # --linger: the server then stays until the client has its end-of-bag status and leaves
    server = serve(bag, "--topics", "control/torque", "/controller/diagnostics", "--wait-subscribers", "1", "--rate", "50",
                   "--linger", str(TIMEOUT_S))

    async def client() -> dict[int, dict[str, Any]]:
        async with _connect(server.url) as ws:
            channels = await _advertised(ws, 2)
            await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": s, "channelId": c} for s, c in enumerate(channels)]}))
            while True:  # subscribed until the bag's end (the server's status), so the server sees the subscriptions
                message = await asyncio.wait_for(ws.recv(), TIMEOUT_S)
                if isinstance(message, str) and json.loads(message).get("op") == "status":
                    return channels  # leaving: the client disconnects, and the lingering server ends

    assert sorted(c["topic"] for c in asyncio.run(client()).values()) == ["/control/torque", "/controller/diagnostics"]
    rc, out, err = server.wait()
    assert rc == 0, err
    assert "sent 402 messages" in out


def _run_cli(args: list[str]) -> tuple[int, str]:
    proc = subprocess.run([sys.executable, "-m", "sappc", *args], capture_output=True, text=True, timeout=TIMEOUT_S, cwd=ROOT)
    return proc.returncode, proc.stderr


@pytest.mark.parametrize(("args", "says"), [
    (["--live", "70000"], "--live: the port must be 0 to 65535, got 70000"),
    (["--live", "-1"], "--live: the port must be 0 to 65535, got -1"),
    (["--live", "x"], "argument --live: invalid int value: 'x'"),
    (["--live", "0", "--rate", "0"], "--rate"),
    (["--live", "0", "--linger", "-1"], "--linger"),
    (["--live", "0", "--start-delay", "-1"], "--start-delay"),
    (["--live", "0", "--wait-subscribers", "-1"], "--wait-subscribers must be >= 0, got -1"),
    (["--live", "0", "--topics", "/nope"], "no topic 'nope' in the bag"),
    (["--live", "0", "--domain-id", "3"], "--domain-id is an option of the ROS 2 replay"),
    (["--host", "0.0.0.0"], "--host is an option of --live"),
    (["--linger", "1"], "--linger is an option of --live"),
    (["--live", "0", "--host", "no.such.host.invalid"], "--live: cannot listen on no.such.host.invalid:0"),
])
def test_bad_options_get_one_line_and_status_2(bag: Path, args: list[str], says: str) -> None:
    rc, err = _run_cli(["replay", str(bag), *args])
    assert rc == 2, err
    assert says in err
    assert "Traceback" not in err and err.strip().splitlines()[-1].startswith(("sappc: error:", "sappc replay: error:")), err


def test_a_port_in_use_gets_one_line_and_status_2(bag: Path) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        rc, err = _run_cli(["replay", str(bag), "--live", str(port)])
    assert rc == 2, err
    assert f"--live: cannot listen on 127.0.0.1:{port}" in err and len(err.strip().splitlines()) == 1, err


def test_not_a_bag_gets_one_line_and_status_2(tmp_path: Path) -> None:
    path = tmp_path / "x.mcap"
    path.write_bytes(b"not an mcap file at all")
    rc, err = _run_cli(["replay", str(path), "--live", "0"])
    assert rc == 2 and "not an MCAP file" in err and len(err.strip().splitlines()) == 1, err


def test_a_bag_cut_short_is_served_up_to_its_cut(bag: Path, tmp_path: Path, serve: Any) -> None:
    """No summary section: the channels come from a walk of the file, the messages up to the tear."""
    raw = _mcap(bag).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(raw[: len(raw) * 2 // 3])
    server = serve(cut, "--rate", "50", "--linger", "0")
    rc, out, err = server.wait()
    assert rc == 0, err
    assert "the bag ends early" in out and re.search(r"sent [1-9]\d* messages", out), out


def test_the_server_module_does_not_import_ros() -> None:
    code = "import sys, sappc.bag.live; assert not [m for m in sys.modules if m.startswith(('rclpy', 'sappc_msgs_py.runtime'))]"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=TIMEOUT_S, env={**os.environ})
