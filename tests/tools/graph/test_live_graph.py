"""``sappc run SCENARIO --live [PORT]`` (issue 51, item 1): the recorder serves every recorded topic
to Foxglove over the Foxglove WebSocket protocol, checked with a client of the protocol
(``websockets``, subprotocol ``foxglove.sdk.v1``, as tests/tools/bag/test_replay_live.py).

- a client connected during the run (five processes, and ``--compose``) receives every recorded
  topic, each message the bag's bytes with the bag's log time, then the run's verdict on
  ``/sappc/run``, as the run prints it; the port is closed once the run has ended;
- the bag of a run with ``--live`` (and a client) is the bag of the run without it, byte for byte,
  and the metrics printed are the same;
- Ctrl-C during a live run: exit status 130 as without it, the port closed.

Every run is experiment 1 cut to 3 s (301 samples, 3311 messages: fewer than the server's queue for
a client, :data:`~sappc.bag.live.MESSAGE_BACKLOG`, so none is dropped however slowly the client
reads) on a port the system picks (``--live 0``, the address read from the line the run prints),
on a ROS domain of its own (the suite's :data:`~sappc.graph.launch.DOMAIN_IDS_ENV`); the runs
wait for the client (``--wait-subscribers 1``: the recorder subscribes to ``/clock``, which starts
the run, once every topic has a subscription), so no wait depends on timing; every process is
killed at the end of its test if still running.
"""

from __future__ import annotations

import asyncio
import json
import re
import signal
import socket
import subprocess
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from sappc.bag.live import MESSAGE_BACKLOG

from conftest import ROOT, SAPPC, SCENARIOS, cut_short

websockets = pytest.importorskip("websockets")

pytestmark = pytest.mark.slow

SUBPROTOCOL = "foxglove.sdk.v1"
#: Generous bounds [s]: a run's start on a loaded machine takes up to a minute.
TIMEOUT_S = 300.0
DURATION_S = 3.0
TIMING = ("wall_time_s", "startup_s", "first_sample_after_nodes_up_s")


@pytest.fixture(scope="module")
def scenario(tmp_path_factory: pytest.TempPathFactory) -> Path:
    raw = cut_short(yaml.safe_load((SCENARIOS / "paper_tracking.yaml").read_text()), DURATION_S)
    path = tmp_path_factory.mktemp("live_run") / "short.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


class Run:
    """A ``sappc run ... --live 0`` process and the address it printed (stderr)."""

    def __init__(self, *args: str) -> None:
        self.proc = subprocess.Popen([*SAPPC, "run", *args], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.err: list[str] = []
        self.out = ""
        self.url = ""
        found = threading.Event()

        def read_err() -> None:
            assert self.proc.stderr is not None
            for line in self.proc.stderr:
                self.err.append(line)
                if not found.is_set() and "live view at ws://" in line:
                    self.url = re.search(r"ws://\S+", line).group(0)  # type: ignore[union-attr]
                    found.set()
            found.set()

        def read_out() -> None:
            assert self.proc.stdout is not None
            self.out = self.proc.stdout.read()

        self.readers = [threading.Thread(target=f, daemon=True) for f in (read_err, read_out)]
        for t in self.readers:
            t.start()
        assert found.wait(TIMEOUT_S) and self.url, f"no address printed: {''.join(self.err)}"
        self.port = int(self.url.rsplit(":", 1)[1])

    def wait(self) -> int:
        rc = self.proc.wait(TIMEOUT_S)
        for t in self.readers:
            t.join(TIMEOUT_S)
        return rc

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(TIMEOUT_S)


@pytest.fixture
def start() -> Iterator[Any]:
    started: list[Run] = []

    def run(*args: str) -> Run:
        started.append(Run(*args))
        return started[-1]

    yield run
    for r in started:
        r.kill()


def _refused(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) != 0


def _bag_messages(bag: Path) -> dict[str, list[tuple[int, bytes]]]:
    """topic -> [(log time, payload)] of the bag, as the ``mcap`` package reads it."""
    from mcap.reader import make_reader

    out: dict[str, list[tuple[int, bytes]]] = {}
    with open(next(bag.glob("*.mcap")), "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            out.setdefault(channel.topic, []).append((message.log_time, bytes(message.data)))
    return out


async def _watch(url: str) -> tuple[dict[int, dict[str, Any]], dict[int, list[tuple[int, bytes]]]]:
    """Connect, subscribe to every channel once all are advertised, and read until the run's
    verdict arrives on /sappc/run or the server closes the connection."""
    async with websockets.connect(url, subprotocols=[SUBPROTOCOL], max_size=None, open_timeout=TIMEOUT_S) as ws:
        assert ws.subprotocol == SUBPROTOCOL
        channels: dict[int, dict[str, Any]] = {}
        while not any(c["topic"] == "/sappc/run" for c in channels.values()) or len(channels) < 12:
            message = await asyncio.wait_for(ws.recv(), TIMEOUT_S)
            if isinstance(message, str) and json.loads(message)["op"] == "advertise":
                channels.update({c["id"]: c for c in json.loads(message)["channels"]})
        subs = dict(enumerate(channels))
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": s, "channelId": c} for s, c in subs.items()]}))
        got: dict[int, list[tuple[int, bytes]]] = {c: [] for c in channels}
        (run_channel,) = [c for c, ch in channels.items() if ch["topic"] == "/sappc/run"]
        try:
            while True:
                message = await asyncio.wait_for(ws.recv(), TIMEOUT_S)
                if isinstance(message, bytes) and message[0] == 0x01:  # opcode, subscription id u32, timestamp u64, payload
                    sub, stamp = int.from_bytes(message[1:5], "little"), int.from_bytes(message[5:13], "little")
                    got[subs[sub]].append((stamp, message[13:]))
                    if subs[sub] == run_channel and json.loads(message[13:])["phase"] == "verdict":
                        break
        except websockets.ConnectionClosed:
            pass
        return channels, got


@pytest.fixture(scope="module")
def plain_run(scenario: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """The scenario run without ``--live``: (run directory, its JSON)."""
    out = tmp_path_factory.mktemp("plain") / "run"
    proc = subprocess.run([*SAPPC, "run", str(scenario), "--out", str(out), "--json", str(out.parent / "m.json")],
                          capture_output=True, text=True, timeout=TIMEOUT_S, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return out, json.loads((out.parent / "m.json").read_text())


@pytest.mark.parametrize("compose", [False, True], ids=["five-processes", "composed"])
def test_a_client_during_the_run_receives_every_topic_as_the_bag_has_it_and_the_bag_is_unchanged(
        compose: bool, scenario: Path, plain_run: tuple[Path, dict[str, Any]], tmp_path: Path, start: Any) -> None:
    out = tmp_path / "run"
    run = start(str(scenario), "--out", str(out), "--json", str(tmp_path / "m.json"), "--live", "0", "--wait-subscribers", "1",
                *(["--compose"] if compose else []))
    channels, got = asyncio.run(_watch(run.url))
    assert run.wait() == 0, "".join(run.err)
    bag = _bag_messages(out / "bag")
    assert sum(len(m) for m in bag.values()) == 3311 <= MESSAGE_BACKLOG  # none can be dropped
    by_topic = {ch["topic"]: got[cid] for cid, ch in channels.items()}
    for cid, ch in channels.items():
        if ch["topic"] != "/sappc/run":
            assert ch["encoding"] == "cdr" and ch["schemaEncoding"] == "ros2msg", ch
    # every recorded topic, every message: the bag's bytes at the bag's log time (per topic, as a multiset)
    assert set(by_topic) - {"/sappc/run"} == set(bag)
    for topic, messages in bag.items():
        assert sorted(by_topic[topic]) == sorted(messages), topic
    # the run's status: the bag closed, then the verdict the run prints as its last line
    status = [json.loads(payload) for _, payload in by_topic["/sappc/run"]]
    assert [s["phase"] for s in status][-2:] == ["closed", "verdict"]
    assert status[-2]["messages"] == 3311 and status[-1]["failed"] is False, (status[-2:], "".join(run.err))
    assert status[-1]["text"] == run.out.strip().splitlines()[-1]
    assert _refused(run.port)  # the server is gone with the run
    assert (out / "bag" / "foxglove_layout.json").read_bytes() == (ROOT / "src" / "sappc" / "data" / "foxglove" / "sappc_layout.json").read_bytes()
    # the bag and metrics equal the run's without --live
    plain_dir, plain = plain_run
    assert (out / "bag" / "bag_0.mcap").read_bytes() == (plain_dir / "bag" / "bag_0.mcap").read_bytes()
    assert (out / "bag" / "metadata.yaml").read_text() == (plain_dir / "bag" / "metadata.yaml").read_text()
    assert bag == _bag_messages(plain_dir / "bag")
    live = json.loads((tmp_path / "m.json").read_text())
    assert {k: v for k, v in live["metrics"].items() if k not in TIMING} == {k: v for k, v in plain["metrics"].items() if k not in TIMING}
    assert live["recorded"] == plain["recorded"] and live["published"] == plain["published"]


def test_ctrl_c_during_a_live_run_exits_130_and_closes_the_port(scenario: Path, tmp_path: Path, start: Any) -> None:
    """No client: the run waits for one (``--wait-subscribers``) until Ctrl-C."""
    run = start(str(scenario), "--out", str(tmp_path / "run"), "--live", "0", "--wait-subscribers", "1")
    run.proc.send_signal(signal.SIGINT)
    assert run.wait() == 130, "".join(run.err)
    assert _refused(run.port)


@pytest.mark.parametrize(("args", "says"), [
    (["--host", "0.0.0.0"], "--host is an option of --live"),
    (["--wait-subscribers", "1"], "--wait-subscribers is an option of --live"),
    (["--live", "70000"], "--live: the port must be 0 to 65535, got 70000"),
    (["--live", "0", "--realtime", "--wait-subscribers", "1"], "--wait-subscribers is for --live in lockstep"),
])
def test_bad_live_options_get_one_line_and_status_2(scenario: Path, tmp_path: Path, args: list[str], says: str) -> None:
    proc = subprocess.run([*SAPPC, "run", str(scenario), "--out", str(tmp_path / "run"), *args], capture_output=True, text=True,
                          timeout=TIMEOUT_S, cwd=ROOT)
    assert proc.returncode == 2, proc.stderr
    assert says in proc.stderr and "Traceback" not in proc.stderr


def test_a_port_in_use_stops_the_run_before_it_starts(scenario: Path, tmp_path: Path) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        proc = subprocess.run([*SAPPC, "run", str(scenario), "--out", str(tmp_path / "run"), "--live", str(port)], capture_output=True,
                              text=True, timeout=TIMEOUT_S, cwd=ROOT)
    assert proc.returncode == 2, proc.stderr
    assert f"--live: cannot listen on 127.0.0.1:{port}" in proc.stderr
    assert not (tmp_path / "run").exists()
