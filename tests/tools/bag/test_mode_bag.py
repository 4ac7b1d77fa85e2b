"""The mode timeline in the bag (issue 49): ``mode/status`` written by ``sappc simulate --record``
(:mod:`sappc.bag.write_offline`) and read back by :mod:`sappc.bag.read` and :mod:`sappc.bag.blocks`.

On ``tests/modes/quick_flight.yaml`` (every mode in 5 s; its verdict fails on purpose, so the data
are compared, not the exit codes):

- the bag's mode record (``History.mode``, ``mode_reason``: (T, 1) int8) is the offline run's, bit
  for bit, sample by sample, read whole or in blocks cut anywhere;
- the metrics from the bag (the mode metrics and the tracking metrics from the TRACK origin, every
  one), the verdict and the modes line are ``sappc simulate``'s, and ``sappc report`` draws
  ``modes.png``; with ``metrics.origin: last_track`` too;
- each ``mode/status`` message is what the mode node publishes (``wire.codec(MODE_STATUS)``, labels
  ``time_s,mode,reason``, ``data[0]`` the sample's stamp in seconds), one per sample, the contract's
  last topic;
- a scenario without modes has no ``mode/status`` channel and its bag no mode record; a sample
  whose message is missing (real time) holds the mode before it, with no reason.
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sappc.bag.blocks import BagBlocks, FullHistory
from sappc.bag.read import Bag, Series, _mode_record, bag_metrics, bag_run, find_topic, read_bag
from sappc.bag.write_offline import OfflineBagWriter, offline_topics
from sappc.cli import main
from sappc.evaluation.requirements import failed_requirements
from sappc.offline.simulate import simulate
from sappc.scenario import load_scenario, read_scenario_mapping, scenario_from_mapping
from sappc_modes.core.modes import MODE_NAMES, R_NONE
from sappc_msgs_py import contract as c
from sappc_msgs_py import wire
from sappc_msgs_py.convert import seconds_to_ns

from conftest import ROOT, SCENARIOS, cut_short

QUICK = ROOT / "tests" / "modes" / "quick_flight.yaml"
#: The metrics a flight's modes decide: the mode metrics and those counted from the TRACK origin.
MODE_METRICS = ("mode_sequence", "time_to_track_s", "time_in_mode_s", "mode_transitions", "settling_time_s", "steady_max_abs_qev",
                "steady_mean_abs_qev", "rpf_error_at_t2", "overshoot", "max_abs_torque_Nm", "torque_sign_changes_per_s",
                "time_outside_constraint_s")


def _cli(argv: list[str]) -> tuple[int, str]:
    """``sappc ARGV`` in this process: (exit status, stdout)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        status = main(argv)
    return status, out.getvalue()


def _modes_line(stdout: str) -> str:
    lines = [line for line in stdout.splitlines() if line.startswith("modes: ")]
    assert len(lines) == 1, stdout
    return lines[0]


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """quick_flight through ``sappc simulate --record --json`` and ``sappc report --json``, and the
    same run's whole offline History."""
    tmp = tmp_path_factory.mktemp("modes_bag")
    bag, sim_json, rep_json = tmp / "bag", tmp / "sim.json", tmp / "rep.json"
    status, sim_out = _cli(["simulate", str(QUICK), "--record", str(bag), "--json", str(sim_json), "--no-progress"])
    assert status != 0  # quick_flight fails its requirements on purpose
    rep_status, rep_out = _cli(["report", str(bag), "--out", str(tmp / "report"), "--json", str(rep_json)])
    scenario = load_scenario(QUICK)
    offline = simulate(scenario).history  # the same run, its whole record kept
    assert offline is not None and offline.mode is not None and offline.mode_reason is not None
    return {"scenario": scenario, "bag": bag, "sim": json.loads(sim_json.read_text()), "sim_out": sim_out, "report": tmp / "report",
            "rep_status": rep_status, "rep": json.loads(rep_json.read_text()), "rep_out": rep_out, "offline": offline}


def test_the_bags_mode_record_is_the_offline_runs_bit_for_bit(recorded: dict[str, Any]) -> None:
    offline = recorded["offline"]
    bag = read_bag(recorded["bag"])
    assert not bag.undecodable and bag.truncated is None
    got = bag_run(bag).history
    assert got.mode is not None and got.mode_reason is not None
    for name in ("mode", "mode_reason"):
        a, b = getattr(offline, name), getattr(got, name)
        assert a.dtype == b.dtype == np.int8 and a.shape == b.shape == (offline.t.size, 1), name
        assert np.array_equal(a, b), name
    # the flight is worth the test: every mode, transitions with their reasons
    assert set(offline.mode[:, 0].tolist()) == set(range(len(MODE_NAMES)))
    assert np.count_nonzero(offline.mode_reason != R_NONE) == 11  # (tests/modes/quick_flight.yaml: twice the online loss of control, a request)
    # read in blocks cut anywhere (the block reader that sappc report and sappc run use): the same
    for block_messages in (1, 37, 1000):
        blocks = BagBlocks(recorded["bag"], block_messages=block_messages)
        sink = FullHistory()
        for h, _answer in blocks.blocks():
            sink.add(h)
        whole = sink.history()
        assert whole.mode is not None and whole.mode_reason is not None
        assert np.array_equal(whole.mode, offline.mode) and np.array_equal(whole.mode_reason, offline.mode_reason), block_messages
        assert whole.mode.dtype == whole.mode_reason.dtype == np.int8


def test_the_metrics_the_verdict_and_the_modes_line_of_the_bag_are_simulates(recorded: dict[str, Any]) -> None:
    sim, rep, scenario = recorded["sim"], recorded["rep"], recorded["scenario"]
    assert recorded["rep_status"] == 0
    simulated = {k: v for k, v in sim["metrics"].items() if k != "wall_time_s"}
    reported = {k: v for k, v in rep["metrics"].items() if k != "wall_time_s"}
    assert reported == simulated  # every metric, the mode metrics and the tracking ones from TRACK's start
    for key in MODE_METRICS:
        assert key in reported, key
    assert reported["mode_sequence"] == ["DETUMBLE"] + ["HOLD", "TRACK", "SAFE"] * 3 + ["HOLD", "TRACK"]
    assert _modes_line(recorded["rep_out"]) == _modes_line(recorded["sim_out"])
    # the verdict: the same failures, from the bag's metrics and controller summary
    ms = scenario.metrics
    bag = read_bag(recorded["bag"])
    run = bag_run(bag)
    metrics, _ = bag_metrics(bag, run=run, steady_from_s=ms.steady_from_s, settle_threshold=ms.settle_threshold, t2_s=ms.t2_s,
                             fault_windows=scenario.event_windows(), orbit_bins=scenario.orbit_bins(), origin=ms.origin)
    assert {k: v for k, v in metrics.items() if k in simulated} == {k: v for k, v in simulated.items() if k in metrics}
    summary = run.controller_summary()
    assert summary["inactive"] == sim["controller_summary"]["inactive"] > 0
    verdict = failed_requirements(metrics, ms.requirements, summary, settle_threshold=ms.settle_threshold)
    assert verdict == sim["failed_requirements"] and verdict
    # no note that mode/status is missing; modes.png drawn
    assert "mode/status" not in recorded["rep_out"]
    assert (recorded["report"] / "modes.png").is_file()


def test_the_last_track_origin_from_the_bag(tmp_path: Path) -> None:
    """``metrics.origin: last_track``: the bag's tracking metrics count from the last entry into
    TRACK, as simulate's (the origin travels from the scenario embedded in the bag)."""
    raw = read_scenario_mapping(QUICK)
    raw["metrics"] = {**raw.get("metrics", {}), "origin": "last_track"}
    scenario = scenario_from_mapping(raw, source=str(QUICK))
    with OfflineBagWriter(scenario, tmp_path / "bag") as writer:
        result = simulate(scenario, history="none", sinks=[writer])
    first = simulate(load_scenario(QUICK), history="none").metrics
    assert result.metrics["settling_time_s"] != first["settling_time_s"] or \
        result.metrics["steady_max_abs_qev"] != first["steady_max_abs_qev"]  # the origins differ
    from sappc.analysis.report import analyse_bag

    analysis = analyse_bag(tmp_path / "bag")
    assert analysis.metrics is not None
    assert {k: v for k, v in analysis.metrics.items() if k != "wall_time_s"} == \
        {k: v for k, v in result.metrics.items() if k != "wall_time_s"}


def test_the_mode_status_messages_are_the_mode_nodes(recorded: dict[str, Any]) -> None:
    from mcap.reader import make_reader
    from rclpy.serialization import deserialize_message

    offline, scenario = recorded["offline"], recorded["scenario"]
    topics = offline_topics(scenario)
    assert topics[-1] is c.MODE_STATUS  # the contract's order: the last of TOPICS (quick_flight relays nothing)
    codec = wire.codec(c.MODE_STATUS)
    T = offline.t.size
    k = 0
    with next(Path(recorded["bag"]).glob("*.mcap")).open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        assert [ch.topic for ch in summary.channels.values()] == ["/" + t.name.lstrip("/") for t in topics]
        for _, channel, message in reader.iter_messages(topics=["/mode/status"], log_time_order=False):
            t_ns = seconds_to_ns(k * scenario.control_period_s)  # the plant's stamp of sample k
            assert message.log_time == message.publish_time == t_ns and message.sequence == k + 1
            mode, reason = int(offline.mode[k, 0]), int(offline.mode_reason[k, 0])
            assert message.data == codec.encode(None, [t_ns / 1e9, float(mode), float(reason)])
            msg = deserialize_message(message.data, c.MODE_STATUS.msg_class)
            assert [(d.label, d.size, d.stride) for d in msg.layout.dim] == [("time_s,mode,reason", 3, 3)]
            assert msg.layout.data_offset == 0 and list(msg.data) == [t_ns / 1e9, mode, reason]
            k += 1
    assert k == T


def test_a_scenario_without_modes_has_no_mode_status(tmp_path: Path) -> None:
    for path in sorted(SCENARIOS.glob("*.yaml")):  # every bundled scenario: the channel iff modes
        scenario = load_scenario(path)
        assert (c.MODE_STATUS in offline_topics(scenario)) == (scenario.modes is not None), path.stem
    scenario = scenario_from_mapping(cut_short(read_scenario_mapping(SCENARIOS / "flight_tracker_outage.yaml"), 0.5), source="outage")
    assert scenario.modes is None
    with OfflineBagWriter(scenario, tmp_path / "bag") as writer:
        simulate(scenario, history="none", sinks=[writer])
    bag = read_bag(tmp_path / "bag")
    assert find_topic(bag, c.MODE_STATUS.name) is None and "/mode/status" not in bag.counts
    history = bag_run(bag).history
    assert history.mode is None and history.mode_reason is None
    assert "mode/status" not in (tmp_path / "bag" / "metadata.yaml").read_text()


def test_a_missing_message_holds_the_mode_before_it_without_a_reason() -> None:
    """A real-time bag may miss a sample's message: the sample keeps the latest mode before it (a
    mode holds until a transition), no reason; before the first message, the first message's mode.
    ``data[0]`` is float seconds, matched within ``STAMP_TOL_NS``."""
    dt_ns = 10_000_000
    stamps = np.arange(1, 7, dtype=np.int64) * dt_ns + 1_700_000_000_000_000_000  # real-time epoch stamps
    values = np.array([[0.0, 1, 0], [0.0, 2, 3], [0.0, 2, 0], [0.0, 3, 4]])  # samples 1, 2, 4, 5 (those of 3 and 6 lost)
    kept = stamps[[0, 1, 3, 4]] + 200  # the float seconds' rounding: within the tolerance
    values[:, 0] = kept / 1e9
    bag = Bag(path=Path("x"), series={"/mode/status": Series(kept, values, kept)},
              array_labels={"/mode/status": c.MODE_STATUS_LAYOUT})
    at = np.concatenate(([stamps[0] - dt_ns], stamps))  # a sample before the first message, then samples 1 .. 6
    record = _mode_record(bag, at)
    assert record["mode"].dtype == record["mode_reason"].dtype == np.int8
    assert record["mode"][:, 0].tolist() == [1, 1, 2, 2, 2, 3, 3]
    assert record["mode_reason"][:, 0].tolist() == [0, 0, 3, 0, 0, 4, 0]
    assert _mode_record(Bag(path=Path("x"), series={}), at) == {}
