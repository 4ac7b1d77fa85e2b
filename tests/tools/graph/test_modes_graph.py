"""Flight modes on the ROS 2 graph (issue 49): the mode node publishes each sample's mode on
``mode/status``, the controller answers outside TRACK with HOLD's and SAFE's law and restarts its
law at each later entry into TRACK, the momentum node flies B-dot in DETUMBLE; a flight through
every mode (``tests/modes/quick_flight.yaml``: DETUMBLE, HOLD, TRACK, SAFE on the online loss of
control, HOLD, TRACK, a ground request to SAFE, ... in 5 s) through ``sappc run`` in lockstep equals the offline run bit for bit, as
separate processes and composed."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

from sappc.bag.read import bag_run, read_bag
from sappc.cli import EXIT_REQUIREMENT_FAILED
from sappc.offline import compiled_loop
from sappc.scenario import load_scenario
from sappc_modes.core.modes import DETUMBLE, HOLD, MODE_NAMES, R_ACQUIRED, R_CONTROL_LOST, R_DETUMBLED, R_RECOVERED, R_REQUEST, REASON_NAMES, SAFE, TRACK
from sappc_msgs_py.contract import ANSWER_INACTIVE, MODE_HEALTH_NAME

from conftest import ROOT, SAPPC

QUICK_FLIGHT = ROOT / "tests" / "modes" / "quick_flight.yaml"


@pytest.fixture(scope="module")
def offline() -> compiled_loop.CompiledRun:
    """The flight offline (its record, the reference the bag is held to)."""
    return compiled_loop.simulate_compiled(load_scenario(QUICK_FLIGHT))


@pytest.mark.slow
@pytest.mark.parametrize("layout", ["processes", "composed"])
def test_a_flight_through_every_mode_on_the_graph_equals_the_offline_run(tmp_path: Path, layout: str,
                                                                         offline: compiled_loop.CompiledRun) -> None:
    """The true state, the controller's torque and funnel rows, the wheels, the estimate, the
    fields and the rods' commands, each sample's mode and the reason of its transition: the bag
    equals the offline record bit for bit; the flight visits every mode, for the reasons the file
    sets (detumbled, acquired, the online loss of control, recovered, acquired, the ground's request...)."""
    out = tmp_path / "run"
    proc = subprocess.run([*SAPPC, "run", str(QUICK_FLIGHT), "--out", str(out), "--json", str(tmp_path / "m.json"),
                           *(["--compose"] if layout == "composed" else [])], capture_output=True, text=True, timeout=600, cwd=ROOT)
    # the flight loses control after its SAFE (a 5 s file; the verdict follows from the metrics, compared below)
    assert proc.returncode == EXIT_REQUIREMENT_FAILED, proc.stdout + proc.stderr
    run = bag_run(read_bag(out / "bag"))
    h, off = run.history, offline.history()
    for name in ("q_BN", "omega_BN_B", "q_BR", "torque_B", "torque_cmd_B", "rho", "wheel_speed_rad_s", "wheel_torque_Nm", "mode", "mode_reason"):
        assert np.array_equal(getattr(h, name), getattr(off, name), equal_nan=True), name
    assert h.estimate is not None and off.estimate is not None
    assert np.array_equal(h.estimate.q_BN, off.estimate.q_BN, equal_nan=True)
    assert h.orbit is not None and off.orbit is not None
    assert np.array_equal(h.orbit[:, 0, :6], off.orbit[:, 0, :6]) and np.array_equal(h.orbit[:, 0, 9:], off.orbit[:, 0, 9:])
    # what the flight exercises: every mode, each transition's reason, B-dot on the rods and nothing on the wheels in DETUMBLE,
    # the controller inactive outside TRACK (its diagnostics' answer), the law's torque in HOLD and SAFE
    mode, reason = h.mode[:, 0], h.mode_reason[:, 0]
    changes = np.flatnonzero(reason != 0)
    taken = [(int(mode[k]), int(reason[k])) for k in changes]
    assert taken[:5] == [(HOLD, R_DETUMBLED), (TRACK, R_ACQUIRED), (SAFE, R_CONTROL_LOST), (HOLD, R_RECOVERED), (TRACK, R_ACQUIRED)]
    assert (SAFE, R_REQUEST) in taken  # the ground's request of 2.5 s
    detumble = mode == DETUMBLE
    assert mode[0] == DETUMBLE and np.abs(h.orbit[detumble, 0, 9:]).max() > 1.0
    assert h.wheel_torque_Nm is not None and np.all(h.torque_B[detumble, 0] == 0.0)
    assert np.all((run.answer == ANSWER_INACTIVE) == (mode != TRACK))
    for m in (HOLD, SAFE):
        assert np.abs(h.torque_B[mode == m, 0]).max() > 0.0, m
    metrics = json.loads((tmp_path / "m.json").read_text())["metrics"]
    assert metrics["mode_sequence"] == ["DETUMBLE", *(MODE_NAMES[m] for m, _ in taken)]
    recorded = {t["topic_metadata"]["name"].lstrip("/"): t["message_count"] for t in
                yaml.safe_load((out / "bag" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]["topics_with_message_count"]}
    assert recorded["mode/status"] == len(mode)
    # the mode in words on diagnostics (beside the estimator's health): at each transition, ERROR in SAFE
    reports = _mode_reports(out / "bag")
    at_changes = [(t_ns, values["mode"], values["reason"], level) for t_ns, level, values in reports
                  if values["since_s"] == values["time_s"] and values["reason"] != "initial"]
    assert [(m, r) for _, m, r, _ in at_changes] == [(MODE_NAMES[m], REASON_NAMES[r]) for m, r in taken]
    assert [t_ns for t_ns, *_ in at_changes] == [int(k) * 10_000_000 for k in changes]
    assert all(level == (2 if values["mode"] == "SAFE" else 0) for _, level, values in reports)
    assert reports[0][2]["mode"] == "DETUMBLE" and reports[0][2]["reason"] == "initial"


def _mode_reports(bag_dir: Path) -> list[tuple[int, int, dict[str, str]]]:
    """The mode node's statuses on ``diagnostics`` in a bag: (stamp [ns], level, key/values)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from mcap.reader import make_reader
    from rclpy.serialization import deserialize_message

    out = []
    with open(next(bag_dir.glob("*.mcap")), "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages(topics=["/diagnostics", "diagnostics"]):
            msg = deserialize_message(message.data, DiagnosticArray)
            for status in msg.status:
                if status.name == MODE_HEALTH_NAME:
                    out.append((msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec, status.level[0],
                                {kv.key: kv.value for kv in status.values}))
    return out


def test_the_graph_refuses_flight_modes_without_an_estimator(tmp_path: Path) -> None:
    """The mode node reads the estimator's estimate, covariance and health: a scenario with modes and
    no estimator stops before any process starts, naming why."""
    raw = load_scenario(QUICK_FLIGHT).raw
    raw["estimator"] = None
    path = tmp_path / "no_estimator.yaml"
    path.write_text(yaml.safe_dump(raw))
    proc = subprocess.run([*SAPPC, "run", str(path), "--out", str(tmp_path / "run")], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 2 and "flight modes (section modes) run on the graph with an estimator only" in proc.stderr, proc.stderr
    assert not (tmp_path / "run" / "bag").exists()
