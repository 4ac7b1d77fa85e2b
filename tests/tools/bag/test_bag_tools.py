"""Reading bags and analysing them, on synthetic bags written by the ``mcap`` package's writer:

- the vectorised CDR decoders equal ``rclpy`` deserialisation, message for message, for every
  frame id length (every alignment), chunked or not, with each compression;
- a bag cut anywhere yields the messages before the cut and says so; not a bag, an empty file,
  a missing file, a bag without the contract's topics give one clear line, never a traceback;
- a bag lacking the reference gives a partial report;
- metrics from a whole history at once equal those of the sample-by-sample observer, bit for bit;
- ROS parameters files -> controller config.
"""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest
from bagmaker import write_bag

from sappc.bag.read import BagError, read_bag
from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import clock_msg, diagnostics_msg, quaternion_msg, torque_msg, vector3_msg
from gnc_common.validation import ConfigError

from conftest import ROOT, SAPPC, SCENARIOS


def _msgs_with_every_alignment(rng: np.random.Generator, n: int = 40) -> list[tuple[str, str, object, int]]:
    """Messages of every contract type; header frame ids of length 0 to 9 (every padding), and the
    transforms' child frame ids of length 0 to 10."""
    from geometry_msgs.msg import QuaternionStamped, TransformStamped, Vector3Stamped, WrenchStamped

    out = []
    for k in range(n):
        t = k * 0.01 + rng.uniform(0, 1e-3)
        frame = "f" * (k % 10)
        q = QuaternionStamped()
        q.header.stamp.sec, q.header.stamp.nanosec, q.header.frame_id = k - 3, int(rng.integers(0, 10**9)), frame
        q.quaternion.x, q.quaternion.y, q.quaternion.z, q.quaternion.w = rng.standard_normal(4).tolist()
        v = Vector3Stamped()
        v.header.stamp.sec, v.header.frame_id = k, frame
        v.vector.x, v.vector.y, v.vector.z = rng.standard_normal(3).tolist()
        w = WrenchStamped()
        w.header.stamp.nanosec, w.header.frame_id = k, frame
        w.wrench.force.x, w.wrench.torque.x, w.wrench.torque.y, w.wrench.torque.z = rng.standard_normal(4).tolist()
        tf = TransformStamped()  # two strings: header frame id and child frame id lengths vary apart
        tf.header.stamp.sec, tf.header.stamp.nanosec, tf.header.frame_id, tf.child_frame_id = k, int(rng.integers(0, 10**9)), frame, "c" * ((3 * k) % 11)
        r, p = tf.transform.rotation, tf.transform.translation
        p.x, p.y, p.z, r.x, r.y, r.z, r.w = rng.standard_normal(7).tolist()
        rows = {label: rng.standard_normal(3) for label in c.DIAGNOSTICS_LAYOUT[1:]}
        log = 1_000_000 * k
        out += [("/q", c.STATE_ATTITUDE.type_name, q, log), ("/v", c.STATE_RATE.type_name, v, log + 1),
                ("/w", c.CONTROL_TORQUE.type_name, w, log + 2), ("/clock", c.CLOCK.type_name, clock_msg(t), log + 3),
                ("/d", c.CONTROLLER_DIAGNOSTICS.type_name, diagnostics_msg(t, rows), log + 4), ("/t", c.STATE_TF.type_name, tf, log + 5)]
    # one Float64MultiArray of another layout and length: parsed on its own
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension

    other = Float64MultiArray()
    other.layout.dim = [MultiArrayDimension(label="x", size=2, stride=2)]
    other.data = [1.5, -2.5]
    out.append(("/d", c.CONTROLLER_DIAGNOSTICS.type_name, other, 10**9))
    return out


def _expected(messages):  # type: ignore[no-untyped-def]
    """The values rclpy's deserialiser gives, per topic (the reader's truth)."""
    from rclpy.serialization import deserialize_message, serialize_message

    exp: dict[str, list] = {}
    for topic, type_name, msg, _ in messages:
        m = deserialize_message(serialize_message(msg), type(msg))
        if topic == "/q":
            s, v = m.header.stamp, [m.quaternion.x, m.quaternion.y, m.quaternion.z, m.quaternion.w]
        elif topic == "/v":
            s, v = m.header.stamp, [m.vector.x, m.vector.y, m.vector.z]
        elif topic == "/w":
            s, v = m.header.stamp, [m.wrench.torque.x, m.wrench.torque.y, m.wrench.torque.z]
        elif topic == "/t":
            r = m.transform.rotation
            s, v = m.header.stamp, [r.x, r.y, r.z, r.w]
        elif topic == "/clock":
            s, v = m.clock, [m.clock.sec + m.clock.nanosec / 1e9]
        else:
            s, v = None, list(m.data)
        ns = None if s is None else s.sec * 1_000_000_000 + s.nanosec
        exp.setdefault(topic, []).append((ns, v, getattr(getattr(m, "header", None), "frame_id", None)))
    return exp


@pytest.mark.parametrize("compression,chunked", [("zstd", True), ("lz4", True), ("none", True), ("none", False)])
def test_decoders_equal_rclpy_for_every_alignment_and_layout(tmp_path, rng, compression, chunked) -> None:  # type: ignore[no-untyped-def]
    messages = _msgs_with_every_alignment(rng)
    bag = read_bag(write_bag(tmp_path / "a.mcap", messages, compression=compression, use_chunking=chunked))
    assert bag.truncated is None and bag.undecodable == {}
    for topic, rows in _expected(messages).items():
        s = bag.series[topic]
        assert s.values.shape[0] == len(rows), topic
        for k, (ns, values, _) in enumerate(rows):
            got = s.values[k][: len(values)]
            assert np.array_equal(got, np.asarray(values)), (topic, k)  # bit for bit
            if ns is not None:
                assert s.stamps_ns[k] == ns, (topic, k)
    assert bag.frame_ids["/q"] == bag.frame_ids["/t"] == tuple(sorted({"f" * n for n in range(10)}))
    assert bag.diagnostics_labels == c.DIAGNOSTICS_LAYOUT
    assert np.isnan(bag.series["/d"].values[-1, 2:]).all()  # the short layout is padded, not invented


def test_a_bag_cut_anywhere_gives_the_messages_before_the_cut(tmp_path, rng) -> None:  # type: ignore[no-untyped-def]
    messages = [("/v", c.STATE_RATE.type_name, vector3_msg([k, 0.0, 0.0], k * 0.01, c.STATE_RATE), k * 10**7) for k in range(3000)]
    whole = write_bag(tmp_path / "whole.mcap", messages, chunk_size=2048).read_bytes()
    for cut in np.linspace(200, len(whole) - 1, 25).astype(int):
        part = tmp_path / f"cut{cut}.mcap"
        part.write_bytes(whole[:cut])
        try:
            bag = read_bag(part)
        except BagError as exc:  # only when nothing at all is readable
            assert "no messages" in str(exc)
            continue
        values = bag.series["/v"].values[:, 0]
        assert bag.truncated is not None
        assert np.array_equal(values, np.arange(values.size, dtype=float))  # a prefix, in order, nothing invented
    # a file cut at 90 % still has most of its messages
    part.write_bytes(whole[: int(0.9 * len(whole))])
    assert read_bag(part).series["/v"].values.shape[0] > 2000


def test_what_is_not_a_bag_gets_one_clear_line(tmp_path) -> None:  # type: ignore[no-untyped-def]
    (tmp_path / "text.mcap").write_text("hello")
    (tmp_path / "empty.mcap").write_bytes(b"")
    (tmp_path / "nobag").mkdir()
    only_other = write_bag(tmp_path / "other.mcap", [])
    cases = {
        tmp_path / "text.mcap": "not an MCAP file",
        tmp_path / "empty.mcap": "not an MCAP file",
        tmp_path / "nobag": "no .mcap file",
        tmp_path / "missing": "no such bag",
        only_other: "no messages of the topic contract",
    }
    for path, words in cases.items():
        with pytest.raises(BagError, match=words):
            read_bag(path)
        proc = subprocess.run([*SAPPC, "report", str(path), "--out", str(tmp_path / "r")], capture_output=True, text=True, cwd=ROOT)
        assert proc.returncode == 2, proc.stderr
        assert "Traceback" not in proc.stderr and words in proc.stderr and len(proc.stderr.strip().splitlines()) == 1


def test_a_bag_without_the_reference_gives_a_partial_report(tmp_path) -> None:  # type: ignore[no-untyped-def]
    messages = []
    for k in range(200):
        t = k * 0.01
        messages += [(c.STATE_ATTITUDE.name, c.STATE_ATTITUDE.type_name, quaternion_msg([0.0, 0.0, 0.0, 1.0], t, c.STATE_ATTITUDE), k),
                     (c.CONTROL_TORQUE.name, c.CONTROL_TORQUE.type_name, torque_msg([0.1, 0.0, 0.0], t, c.CONTROL_TORQUE), k)]
    path = write_bag(tmp_path / "partial.mcap", messages)
    out = tmp_path / "report"
    proc = subprocess.run([*SAPPC, "report", str(path), "--out", str(out), "--json", str(tmp_path / "r.json")],
                          capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr
    summary = json.loads((tmp_path / "r.json").read_text())
    assert summary["metrics"] is None
    assert any("state/rate" in p and "reference/attitude" in p for p in summary["problems"])
    assert summary["messages"] == {"state/attitude": 200, "control/torque": 200}
    page = (out / "report.html").read_text()
    assert "reference/attitude" in page and "<img" not in page  # the page says why, and shows no invented figure


def test_metrics_of_a_whole_history_equal_the_sample_by_sample_observer() -> None:
    """`sappc simulate` (and bags) compute the metrics from the stored history in one block; Monte
    Carlo campaigns observe sample by sample.  Same numbers, bit for bit."""
    import dataclasses

    from sappc.scenario import load_scenario
    from sappc.offline.simulate import run_scenario, simulate

    scenario = load_scenario(SCENARIOS / "paper_fault.yaml")  # faults: every metric has a value
    scenario = dataclasses.replace(scenario, faults=())  # the offline runner refuses relayed faults
    block = simulate(scenario).metrics
    per_sample, _ = run_scenario(scenario)
    assert block["returned_at_s"] is not None and block["left_constraint_after_fault"] is True
    for key, value in per_sample.run_metrics(0).items():
        assert block[key] == value, key  # exactly: the block sums in the same order


def test_time_outside_the_band_on_a_jittered_grid_sums_the_hold_intervals() -> None:
    """Real-time stamps: each sample outside the band counts until the next sample (zero-order
    hold), the last one for the median interval; on the uniform grid it is count * dt exactly.
    Fed as one block and sample by sample, the sums are identical (both sequential)."""
    from sappc.evaluation.metrics import MetricsAccumulator

    t = np.array([0.0, 0.0101, 0.0199, 0.0302, 0.0398, 0.0500])
    outside = np.array([False, True, True, False, False, True])  # samples 1, 2 and 5
    q_BR = np.zeros((6, 1, 4))
    q_BR[..., 3] = 1.0
    q_BR[outside, 0, 0] = 0.5  # the band is [-0.1, 0.1] on every axis
    band = np.full((6, 1, 3), 0.1)
    args = dict(x=np.zeros((6, 1, 7)), torque_B=np.zeros((6, 1, 3)), q_BR=q_BR, rho=np.zeros((6, 1, 3)),
                saturated=np.zeros((6, 1, 3), dtype=bool), band_lower=-band, band_upper=band)

    def accumulator(times):  # type: ignore[no-untyped-def]
        return MetricsAccumulator(times, 1, steady_from_s=1.0, settle_threshold=1e-3, t2_s=1.0, fault_windows=[])

    block = accumulator(t)
    block.update(0, t, **args)
    one_by_one = accumulator(t)
    for k in range(6):
        one_by_one.update(k, t[k : k + 1], **{name: v[k : k + 1] for name, v in args.items()})
    median = np.median(np.diff(t))
    expected = (t[2] - t[1]) + (t[3] - t[2]) + median
    assert block.run_metrics()["time_outside_constraint_s"] == pytest.approx(expected, rel=1e-15)
    assert one_by_one.run_metrics()["time_outside_constraint_s"] == block.run_metrics()["time_outside_constraint_s"]
    uniform = accumulator(np.arange(6) * 0.01)
    uniform.update(0, np.arange(6) * 0.01, **args)
    assert uniform.run_metrics()["time_outside_constraint_s"] == 3 * 0.01


def test_parameters_files_give_the_controller_config(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from sappc.scenario import load_scenario
    from sappc_controller.params import controller_from_parameters_file, parameters_from_yaml

    kind, config, dt = controller_from_parameters_file((ROOT / "config" / "controller_trappc.yaml").read_text())
    assert kind == "trappc" and dt == 0.01
    assert config == load_scenario(SCENARIOS / "paper_tracking.yaml").controller_config("trappc")
    text = "/**:\n  ros__parameters:\n    a: 1\n    b: {c: 2}\ncontroller:\n  ros__parameters:\n    a: 3\n"
    assert parameters_from_yaml(text) == {"a": 3, "b.c": 2}
    with pytest.raises(ConfigError, match="no ros__parameters for node 'controller'"):
        parameters_from_yaml("other:\n  ros__parameters: {a: 1}\n")
    bad = (ROOT / "config" / "controller_sappc.yaml").read_text().replace("K_q:", "K_qq:")
    with pytest.raises(ConfigError, match="unknown parameter 'sappc.gains.K_qq'"):
        controller_from_parameters_file(bad, source="bad.yaml")


def test_a_real_time_bag_without_diagnostics_interpolates_the_reference_and_leaves_unknowns_null(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """State at 100 Hz, reference at 100 Hz stamped 4 ms later (real time: no common stamps), no
    controller/diagnostics.  The reference rotates about z at 0.1 rad/s and the body holds the
    identity, so the true error is q_ev = (0, 0, -sin(w t / 2)); the normalised lerp between
    samples 10 ms apart is exact to ~1e-9 here (the chord's angle error, (w dt)^2 / 8 ~ 1e-7 rad,
    enters q_ev scaled by w t / 2 at most 0.1)."""
    from sappc.analysis.report import analyse_bag

    w = 0.1
    messages = []
    for k in range(400):
        ts, tr = k * 0.01, k * 0.01 + 0.004
        qr = [0.0, 0.0, np.sin(w * tr / 2), np.cos(w * tr / 2)]
        messages += [
            (c.STATE_ATTITUDE.name, c.STATE_ATTITUDE.type_name, quaternion_msg([0.0, 0.0, 0.0, 1.0], ts, c.STATE_ATTITUDE), k),
            (c.STATE_RATE.name, c.STATE_RATE.type_name, vector3_msg([0.0, 0.0, 0.0], ts, c.STATE_RATE), k),
            (c.REFERENCE_ATTITUDE.name, c.REFERENCE_ATTITUDE.type_name, quaternion_msg(qr, tr, c.REFERENCE_ATTITUDE), k),
            (c.CONTROL_TORQUE.name, c.CONTROL_TORQUE.type_name, torque_msg([0.01, 0.0, -0.02], ts, c.CONTROL_TORQUE), k),
        ]
    a = analyse_bag(write_bag(tmp_path / "rt.mcap", messages))
    h = a.run.history
    assert a.run.t0_ns == 10_000_000 and h.t[0] == 0.0  # the first state after the first reference
    expected = -np.sin(w * (h.t + 0.01) / 2)  # h.t counts from that first aligned state
    assert np.abs(h.q_ev[:, 0, 2] - expected).max() < 1e-9
    assert np.abs(h.q_ev[:, 0, :2]).max() == 0.0
    assert a.metrics["max_abs_torque_Nm"] == 0.02 and a.metrics["overshoot"] == 0.0
    for key in ("rpf_error_at_t2", "saturation_fraction", "time_outside_constraint_s"):
        assert a.metrics[key] is None, key  # unknown without diagnostics, not zero
    assert any("no controller/diagnostics" in p for p in a.problems)


def test_the_run_summary_counts_what_the_controller_did_and_sets_the_exit_status() -> None:
    """``sappc run`` reports, from the diagnostics, how the controller answered each sample
    (computed, watchdog zero, no answer, refused) and the rejected inputs; it exits 3 when the
    controller never commanded a torque, 4 when the run broke a requirement, 1 on a count
    mismatch, else 0."""
    from sappc.bag.read import BagRun
    from sappc.cli import EXIT_CONTROLLER_NEVER_COMMANDED, EXIT_REQUIREMENT_FAILED, run_exit_status

    def run(answer: list[int], rejected: int, diagnostics: bool = True) -> BagRun:
        return BagRun(history=None, t0_ns=0, answer=np.array(answer, dtype=np.int8), rejected=rejected, torque_topic=None,  # type: ignore[arg-type]
                      has_diagnostics=diagnostics)

    s = run([0, 1, 1, 2, 3, 0], 7).controller_summary()
    assert s == {"samples": 6, "commanded": 2, "watchdog_zero": 2, "held": 1, "refused": 1, "inactive": 0, "rejected_inputs": 7}
    assert run_exit_status({}, s) == 0 and run_exit_status({"/state/rate": (10, 9)}, s) == 1
    assert run_exit_status({}, s, ["steady_max_abs_qev = 2e-4 > 1e-4"]) == EXIT_REQUIREMENT_FAILED == 4
    never = run([1, 1, 3], 0).controller_summary()
    assert never["commanded"] == 0 and run_exit_status({}, never) == EXIT_CONTROLLER_NEVER_COMMANDED == 3
    assert run_exit_status({}, never, ["time_outside_constraint_s = 0.03 > 0"]) == 3  # never commanded says more than a requirement
    unknown = run([0, 0], 0, diagnostics=False).controller_summary()
    assert unknown["commanded"] is None and run_exit_status({}, unknown) == 0  # a plant of one's own without diagnostics


def test_every_metric_a_run_reports_has_one_clear_sentence_for_the_report() -> None:
    """The HTML report's "meaning" column: every key `sappc simulate` and `sappc run` report (a
    faulty run has the common ones; the estimator's and the wheels' are named in the metrics
    module's definitions) has a sentence of its own: one sentence, no two alike, none saying
    "None" where the table shows "-"."""
    import re

    from sappc.analysis.report import METRIC_SENTENCES, metric_meanings
    from sappc.evaluation import metrics
    from sappc.offline.simulate import simulate
    from sappc.scenario import load_scenario

    result = simulate(load_scenario(SCENARIOS / "paper_fault.yaml"))
    per_run = (metrics.__doc__ or "").split("Definitions, per run:", 1)[1].split("Per orbit (", 1)[0]  # per orbit: its own table
    defined = {n.strip().strip("`") for line in per_run.splitlines() if line.startswith("``") for n in line.split(",")}
    defined |= {"left_constraint_after_fault", "returned_at_s"}  # defined in returned_to_constraint's paragraph
    assert set(METRIC_SENTENCES) == defined | {"wall_time_s", "startup_s", "first_sample_after_nodes_up_s"} and set(result.metrics) <= set(METRIC_SENTENCES)
    assert metric_meanings() == METRIC_SENTENCES
    sentences = list(METRIC_SENTENCES.values())
    assert len(set(sentences)) == len(sentences)
    for name, text in METRIC_SENTENCES.items():
        assert text[0].isupper() and text.endswith(".") and "None" not in text, name
        assert len(re.findall(r"[.:] [A-Z]", text)) == 0 and len(text) > 30, name  # one sentence
