"""The Foxglove layout shipped in ``config/foxglove/sappc_layout.json`` cannot drift from the topic
contract: every message path it references names a topic of the contract (or the output of its own
user script) and a field that the topic's message type has (for ``controller/diagnostics``, the
row of :data:`~sappc_msgs_py.contract.DIAGNOSTICS_LAYOUT` its label says); the 3D panel follows a
contract frame and shows the transform topics; the user script's arithmetic is the project's
``error_quaternion``.  No ROS graph: message classes and numpy only."""

from __future__ import annotations

import json
import re
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from gnc_common.attitude import error_quaternion
from sappc_msgs_py import contract as c

from conftest import ROOT, random_unit_quaternions

LAYOUT = ROOT / "config" / "foxglove" / "sappc_layout.json"
#: Prefix Foxglove gives the output topics of user scripts.
SCRIPT_PREFIX = "/studio_script/"


@pytest.fixture(scope="module")
def layout() -> dict[str, Any]:
    data: dict[str, Any] = json.loads(LAYOUT.read_text())
    return data


def _contract_topics() -> dict[str, c.Topic]:
    return {"/" + t.name.lstrip("/"): t for t in c.TOPICS}


def _leaves(tree: Any) -> list[str]:
    """Panel ids of a mosaic layout tree (a panel id, or a split with ``first`` and ``second``)."""
    if isinstance(tree, str):
        return [tree]
    assert set(tree) >= {"direction", "first", "second"}, tree
    assert tree["direction"] in ("row", "column")
    return _leaves(tree["first"]) + _leaves(tree["second"])


def _scripts(layout: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Each user script's output topic -> {inputs, fields (of its Output type), source}."""
    out = {}
    for script in layout["userNodes"].values():
        src = script["sourceCode"]
        inputs = json.loads(re.search(r"export const inputs = (\[.*?\]);", src).group(1))  # type: ignore[union-attr]
        output = json.loads(re.search(r"export const output = (\".*?\");", src).group(1))  # type: ignore[union-attr]
        fields = re.findall(r"(\w+): number", re.search(r"type Output = \{(.*?)\};", src).group(1))  # type: ignore[union-attr]
        out[output] = {"inputs": inputs, "fields": fields, "source": src}
    return out


def _message_paths(layout: dict[str, Any]) -> list[tuple[str, str, str]]:
    """(panel id, message path, label) of every message path a panel plots or shows."""
    found = []
    for panel_id, config in layout["configById"].items():
        for p in config.get("paths", []):
            found.append((panel_id, p["value"], p.get("label", "")))
        if "path" in config:  # Indicator
            found.append((panel_id, config["path"], config.get("foxglovePanelTitle", "")))
    return found


def test_the_layout_is_a_foxglove_layout_whose_panels_are_all_placed(layout) -> None:  # type: ignore[no-untyped-def]
    assert set(layout) == {"configById", "globalVariables", "userNodes", "playbackConfig", "layout"}
    placed = _leaves(layout["layout"])
    assert sorted(placed) == sorted(layout["configById"]), "every configured panel is placed once, and only those"
    kinds = {panel_id.split("!", 1)[0] for panel_id in placed}
    assert kinds == {"3D", "Plot", "Indicator", "DiagnosticSummary", "DiagnosticStatusPanel"}
    for config in layout["configById"].values():
        for p in config.get("paths", []):
            assert p["enabled"] is True and p["timestampMethod"] == "receiveTime"  # a lockstep bag logs each message at its stamp


def test_every_message_path_names_a_contract_topic_and_a_field_of_its_type(layout) -> None:  # type: ignore[no-untyped-def]
    topics = _contract_topics()
    scripts = _scripts(layout)
    paths = _message_paths(layout)
    assert len(paths) >= 20
    n_rows = len(c.DIAGNOSTICS_LAYOUT)
    for panel_id, path, label in paths:
        topic, _, fields = path.partition(".")
        assert fields, (panel_id, path)
        if topic.startswith(SCRIPT_PREFIX):
            assert topic in scripts, (panel_id, path)
            assert fields in scripts[topic]["fields"], (panel_id, path)
            continue
        assert topic in topics, f"{panel_id}: {path} is not a topic of the contract"
        msg = topics[topic].msg_class()
        index = re.fullmatch(r"data\[(\d+)\]", fields)
        labelled = {c.ESTIMATOR_DIAGNOSTICS.name: c.ESTIMATOR_DIAGNOSTICS_LAYOUT, c.MODE_STATUS.name: c.MODE_STATUS_LAYOUT,
                    c.CONTROL_DIPOLE.name: ("time_s", "rod_1", "rod_2", "rod_3")}
        if index and topics[topic].name in labelled:  # one value per label: the plot's label names it
            names = labelled[topics[topic].name]
            assert int(index.group(1)) < len(names) and names[int(index.group(1))] in label.lower(), (panel_id, path, label)
            continue
        wheel = re.fullmatch(r"(?:velocity|effort)\[(\d+)\]", fields)
        if wheel:  # joint_states: one joint per wheel, wheel_1 .. wheel_N (the flights' four)
            assert topics[topic] is c.WHEEL_STATES and hasattr(msg, fields.split("[")[0]) and label.startswith(f"wheel_{int(wheel.group(1)) + 1} "), (panel_id, path)
            continue
        if index:  # controller/diagnostics: a flat float64 array of labelled rows of 3
            assert topics[topic] is c.CONTROLLER_DIAGNOSTICS, (panel_id, path)
            i = int(index.group(1))
            assert 0 <= i < 3 * n_rows, (panel_id, path)
            row, axis = c.DIAGNOSTICS_LAYOUT[i // 3], i % 3
            # the label (or the indicator's title, for the answer code) says which row and component it is
            assert f"{row}_{'xyz'[axis]}" in label or f"{row}[{axis}]" in label or (row, axis) == ("status", 2), (panel_id, path, label)
            continue
        value: Any = msg
        for name in fields.split("."):
            assert hasattr(value, name), f"{panel_id}: {path}: {type(value).__name__} has no field {name!r}"
            value = getattr(value, name)
        assert isinstance(value, float), (panel_id, path)


def test_the_funnel_plots_show_q_ev_with_rho_and_the_band_of_the_same_axis(layout) -> None:  # type: ignore[no-untyped-def]
    row = {label: i for i, label in enumerate(c.DIAGNOSTICS_LAYOUT)}
    for axis, a in enumerate("xyz"):
        values = [p["value"] for p in layout["configById"][f"Plot!qev_{a}"]["paths"]]
        assert values == [f"{SCRIPT_PREFIX}q_ev.{a}"] + [f"/controller/diagnostics.data[{3 * row[r] + axis}]" for r in ("rho", "band_lower", "band_upper")]
    torque = [p["value"] for p in layout["configById"]["Plot!torque"]["paths"]]
    assert torque == [f"/{c.CONTROL_TORQUE.name}.wrench.torque.{a}" for a in "xyz"]
    indicator = layout["configById"]["Indicator!answer"]
    assert indicator["path"] == f"/controller/diagnostics.data[{3 * row['status'] + 2}]"  # status[2]: the answer code
    assert [(r["rawValue"], r["label"]) for r in indicator["rules"]] == [(str(code), name) for code, name in enumerate(c.ANSWER_NAMES)]


def test_the_3d_panel_follows_the_inertial_frame_and_shows_the_contract_frames(layout) -> None:  # type: ignore[no-untyped-def]
    panel = layout["configById"]["3D!attitude"]
    assert panel["followTf"] == c.Frame.INERTIAL.value
    assert {key.removeprefix("frame:") for key in panel["transforms"]} == {f.value for f in c.Frame}
    topics = _contract_topics()
    assert set(panel["topics"]) == {"/" + t.name for t in c.TRANSFORM_TOPICS}
    for name in panel["topics"]:
        assert topics[name].type_name == "geometry_msgs/msg/TransformStamped"  # Foxglove builds its frame tree from these
    assert {t.child_frame_id for t in c.TRANSFORM_TOPICS} | {t.frame_id for t in c.TRANSFORM_TOPICS} == {f.value for f in c.Frame}
    for layer in panel["layers"].values():
        assert layer.get("frameId", c.Frame.INERTIAL.value) in {f.value for f in c.Frame}


def test_the_user_script_reads_contract_topics(layout) -> None:  # type: ignore[no-untyped-def]
    topics = _contract_topics()
    (script,) = _scripts(layout).values()
    assert script["inputs"] == ["/" + c.STATE_ATTITUDE.name, "/" + c.TRUTH_ATTITUDE.name, "/" + c.REFERENCE_ATTITUDE.name]
    assert all(topics[t].type_name == "geometry_msgs/msg/QuaternionStamped" for t in script["inputs"])
    assert set(script["fields"]) == {"x", "y", "z", "w"}


def _run_script_arithmetic(source: str, q_RN: np.ndarray, q_BN: np.ndarray) -> np.ndarray:
    """The script's lines between ``BEGIN`` and ``END`` and its return value, evaluated in Python:
    they are ``const NAME = EXPR;`` statements whose expressions use only ``+ - *``, fields and
    one ``cond ? a : b``, which mean the same in both languages once the conditional is rewritten."""
    block = source.split("// BEGIN", 1)[1].split("// END", 1)[0].splitlines()[1:]
    env: dict[str, Any] = {"a": SimpleNamespace(**dict(zip("xyzw", map(float, q_RN)))), "b": SimpleNamespace(**dict(zip("xyzw", map(float, q_BN))))}
    for line in filter(str.strip, block):
        m = re.fullmatch(r"\s*const (\w+) = (.+);", line)
        assert m, f"not a 'const NAME = EXPR;' statement: {line!r}"
        expr = m.group(2)
        cond = re.fullmatch(r"(.+?) \? (.+?) : (.+)", expr)
        if cond:
            expr = f"({cond.group(2)}) if ({cond.group(1)}) else ({cond.group(3)})"
        assert re.fullmatch(r"[\w.\s*+\-()<>0-9]+|\(.+\) if \(.+\) else \(.+\)", expr), expr
        env[m.group(1)] = eval(expr, {"__builtins__": {}}, env)  # noqa: S307 (the repository's own file, checked above)
    ret = re.search(r"return \{ x: (.+?), y: (.+?), z: (.+?), w: (.+?) \};", source)
    assert ret, "the script returns {x, y, z, w}"
    return np.array([eval(e, {"__builtins__": {}}, env) for e in ret.groups()])  # noqa: S307


def test_the_diagnostics_panels_show_the_health_topic_and_the_mode_managers_status(layout) -> None:  # type: ignore[no-untyped-def]
    cfg = layout["configById"]
    assert cfg["DiagnosticSummary!health"]["topicToRender"] == "/" + c.ESTIMATOR_HEALTH.name
    status = cfg["DiagnosticStatusPanel!mode"]
    assert status["topicToRender"] == "/" + c.ESTIMATOR_HEALTH.name and status["selectedName"] == c.MODE_HEALTH_NAME
    assert c.ESTIMATOR_HEALTH.type_name == "diagnostic_msgs/msg/DiagnosticArray"
    from sappc_modes.core.modes import MODE_NAMES

    assert [(r["rawValue"], r["label"]) for r in cfg["Indicator!mode"]["rules"]] == [(str(i), n) for i, n in enumerate(MODE_NAMES)]


def test_the_user_script_computes_q_ev_as_the_project_does(layout, rng) -> None:  # type: ignore[no-untyped-def]
    """q_BR = q_RN* (x) q_BN with q0 >= 0, the project's ``error_quaternion``, on random attitudes
    (about half need the sign flip) and on a known one: body turned +90 deg about z, reference at
    identity, so q_ev = (0, 0, sin 45 deg)."""
    (script,) = _scripts(layout).values()
    q_RN = random_unit_quaternions(rng, 200)
    q_BN = random_unit_quaternions(rng, 200)
    got = np.array([_run_script_arithmetic(script["source"], a, b) for a, b in zip(q_RN, q_BN)])
    np.testing.assert_allclose(got, error_quaternion(q_RN, q_BN), atol=1e-15)
    half = np.pi / 4
    np.testing.assert_allclose(_run_script_arithmetic(script["source"], np.array([0.0, 0.0, 0.0, 1.0]), np.array([0.0, 0.0, np.sin(half), np.cos(half)])),
                               [0.0, 0.0, np.sin(half), np.cos(half)], atol=1e-15)
    assert 50 < int(((q_RN * q_BN).sum(axis=1) < 0).sum()) < 150  # the scalar part of q_RN* (x) q_BN: both signs exercised
