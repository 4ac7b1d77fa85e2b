"""The shipped Foxglove layout against a recorded bag (issue 51): every topic a panel of
``sappc/data/foxglove/sappc_layout.json`` plots, shows or feeds its user script is a channel of a
bag of ``sappc simulate --record``, and every message path resolves, field by field and index by
index, in that channel's own ``ros2msg`` schema (the text Foxglove parses, read from the bag, not the
project's message classes: ``tests/tools/test_foxglove_layout.py`` checks the layout against the
contract) to a number.

Two bags: experiment 1's (attitude error, funnel, torque, the controller's diagnostics, the frames)
and a flight's (``tests/modes/quick_flight.yaml``: sensors, estimator, wheels, momentum management,
flight modes).  Every path is in one of them at least; the panels of experiment 1 work on both (a
flight has no ``state/attitude``: the attitude error's script takes ``truth/attitude``), those of a
flight on the flight's.  The diagnostics panels read ``/diagnostics``, which only a graph run
records (the nodes publish it; ``sappc simulate --record`` does not): they are checked against the
contract in ``tests/tools/test_foxglove_layout.py``.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from conftest import ROOT

LAYOUT = ROOT / "src" / "sappc" / "data" / "foxglove" / "sappc_layout.json"
SCRIPT_PREFIX = "/studio_script/"
NUMERIC = {"bool", "byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "float32", "float64"}
PRIMITIVE = NUMERIC | {"string", "wstring"}
#: ``Header`` in a ros2msg definition means ``std_msgs/Header`` (as in ROS 1's and rosbag2's definitions).
ALIASES = {"Header": "std_msgs/Header"}


def _definitions(schema_name: str, text: str) -> dict[str, list[tuple[str, str]]]:
    """The message types of a ros2msg schema (the main one, then each ``MSG: pkg/Type`` after a line
    of ``=``): type -> [(field type, field name)], types as ``pkg/Type``; constants left out."""
    pkg, _, name = schema_name.partition("/msg/")
    blocks = re.split(r"^=+\s*$", text, flags=re.M)
    out: dict[str, list[tuple[str, str]]] = {}
    for i, block in enumerate(blocks):
        lines = [ln.split("#", 1)[0].strip() for ln in block.splitlines()]
        lines = [ln for ln in lines if ln]
        if i == 0:
            full = f"{pkg}/{name}"
        else:
            assert lines and lines[0].startswith("MSG: "), block[:80]
            full = lines.pop(0)[5:].strip().replace("/msg/", "/")
        fields = []
        for ln in lines:
            if "=" in ln:
                continue  # a constant (TYPE NAME=VALUE); a field's default value has no "="
            ftype, fname = ln.split()[:2]
            fields.append((ftype, fname))
        out[full] = fields
    return out


def _resolve(defs: dict[str, list[tuple[str, str]]], root: str, path: str) -> str:
    """The type a Foxglove message path (``a.b[0].c``) reaches from the type ``root``."""
    current = root
    for part in path.split("."):
        m = re.fullmatch(r"(\w+)(?:\[(\d+)\])?", part)
        assert m, f"{path}: {part!r} is not a field (or field[index])"
        field, index = m.group(1), m.group(2)
        types = dict((n, t) for t, n in defs[current])
        assert field in types, f"{path}: {current} has no field {field!r} (it has {sorted(types)})"
        ftype = types[field]
        array = re.fullmatch(r"(.+?)\[(<=)?(\d*)\]", ftype)
        if array:
            assert index is not None, f"{path}: {field} is an array ({ftype}); the path gives no index"
            if array.group(3) and not array.group(2):
                assert int(index) < int(array.group(3)), f"{path}: index {index} past {ftype}"
            ftype = array.group(1)
        else:
            assert index is None, f"{path}: {field} ({ftype}) is not an array"
        ftype = re.sub(r"<=\d+$", "", ftype)  # bounded strings
        if ftype in PRIMITIVE:
            current = ftype
            continue
        ftype = ALIASES.get(ftype, ftype)
        current = ftype if "/" in ftype else f"{current.split('/')[0]}/{ftype}"
        assert current in defs, f"{path}: the schema does not define {current}"
    return current


#: The panels of experiment 1, which must work on a flight's bag too.
EXPERIMENT_1_PANELS = ("Plot!qev_x", "Plot!qev_y", "Plot!qev_z", "Plot!torque", "Plot!status", "Indicator!answer", "3D!attitude")


def _recorded_schemas(out: Path, scenario: str, duration: str) -> dict[str, tuple[str, str]]:
    """topic -> (schema name, schema text) of ``sappc simulate SCENARIO --duration D --record OUT``."""
    from mcap.reader import make_reader

    proc = subprocess.run([sys.executable, "-m", "sappc", "simulate", scenario, "--duration", duration, "--record", str(out),
                           "--no-progress"], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert out.is_dir(), proc.stderr  # the run's verdict (a run cut short settles nowhere) is not the point
    assert (out / "foxglove_layout.json").read_bytes() == LAYOUT.read_bytes()  # the layout written beside the bag
    with open(next(out.glob("*.mcap")), "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    result = {}
    for c in summary.channels.values():
        s = summary.schemas[c.schema_id]
        assert s.encoding == "ros2msg" and c.message_encoding == "cdr", c.topic
        result[c.topic] = (s.name, s.data.decode())
    return result


@pytest.fixture(scope="module")
def schemas(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[str, str]]:
    """Experiment 1's bag (1 s)."""
    return _recorded_schemas(tmp_path_factory.mktemp("layout") / "bag", "paper_tracking", "1")


@pytest.fixture(scope="module")
def flight_schemas(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[str, str]]:
    """A flight's bag (quick_flight, 1 s: every topic of a flight with sensors, estimator, wheels and modes)."""
    return _recorded_schemas(tmp_path_factory.mktemp("layout_flight") / "bag", str(ROOT / "tests" / "modes" / "quick_flight.yaml"), "1")


@pytest.fixture(scope="module")
def layout() -> dict[str, Any]:
    data: dict[str, Any] = json.loads(LAYOUT.read_text())
    return data


def _paths(layout: dict[str, Any]) -> list[tuple[str, str]]:
    """(panel id, message path) of every path a panel plots or shows."""
    found = []
    for panel_id, config in layout["configById"].items():
        found += [(panel_id, p["value"]) for p in config.get("paths", [])]
        if "path" in config:
            found.append((panel_id, config["path"]))
    return found


def _script_inputs(layout: dict[str, Any]) -> dict[str, list[str]]:
    out = {}
    for script in layout["userNodes"].values():
        src = script["sourceCode"]
        inputs = json.loads(re.search(r"export const inputs = (\[.*?\]);", src).group(1))  # type: ignore[union-attr]
        output = json.loads(re.search(r"export const output = (\".*?\");", src).group(1))  # type: ignore[union-attr]
        out[output] = inputs
    return out


def test_the_schema_reader_resolves_what_foxglove_would(schemas: dict[str, tuple[str, str]]) -> None:
    name, text = schemas["/control/torque"]
    defs = _definitions(name, text)
    assert _resolve(defs, "geometry_msgs/WrenchStamped", "wrench.torque.z") == "float64"
    assert _resolve(defs, "geometry_msgs/WrenchStamped", "header.stamp.sec") == "int32"
    for bad in ("wrench.torque.w", "wrench.torque", "wrench[0].torque.x", "header.frame_id[1]"):
        with pytest.raises(AssertionError):
            assert _resolve(defs, "geometry_msgs/WrenchStamped", bad) in NUMERIC
    name, text = schemas["/controller/diagnostics"]
    assert _resolve(_definitions(name, text), "std_msgs/Float64MultiArray", "data[29]") == "float64"


def test_every_topic_and_message_path_of_the_layout_is_in_the_bags_schemas(layout: dict[str, Any],
                                                                             schemas: dict[str, tuple[str, str]],
                                                                             flight_schemas: dict[str, tuple[str, str]]) -> None:
    scripts = _script_inputs(layout)
    paths = _paths(layout)
    assert len(paths) >= 35
    for panel_id, path in paths:
        topic, _, fields = path.partition(".")
        if topic.startswith(SCRIPT_PREFIX):
            assert topic in scripts, (panel_id, path)  # its inputs: the next test
            continue
        bags = [b for b in (schemas, flight_schemas) if topic in b]
        assert bags, f"{panel_id}: {topic} is a topic of neither bag ({sorted(schemas)}, {sorted(flight_schemas)})"
        if panel_id in EXPERIMENT_1_PANELS:
            assert len(bags) == 2, f"{panel_id}: {topic} is not in both bags"
        for bag in bags:
            name, text = bag[topic]
            leaf = _resolve(_definitions(name, text), name.replace("/msg/", "/"), fields)
            assert leaf in NUMERIC, f"{panel_id}: {path} is a {leaf}, not a number"


@pytest.mark.parametrize("bag", ["tracking", "flight"])
def test_the_scripts_inputs_and_the_3d_panels_topics_are_in_the_bag(layout: dict[str, Any], bag: str, schemas: dict[str, tuple[str, str]],
                                                                     flight_schemas: dict[str, tuple[str, str]]) -> None:
    """The attitude error's script: the reference and a body attitude (state/attitude, or a flight's
    truth/attitude) in each bag, each input the bag has a quaternion with a stamp."""
    schemas = schemas if bag == "tracking" else flight_schemas
    for output, inputs in _script_inputs(layout).items():
        assert "/reference/attitude" in schemas and {"/state/attitude", "/truth/attitude"} & set(schemas), output
        for topic in inputs:
            if topic not in schemas:
                continue
            name, text = schemas[topic]
            defs = _definitions(name, text)
            for a in ("w", "x", "y", "z"):  # the script reads quaternion.{w,x,y,z} and header.stamp
                assert _resolve(defs, name.replace("/msg/", "/"), f"quaternion.{a}") == "float64"
            assert _resolve(defs, name.replace("/msg/", "/"), "header.stamp.nanosec") == "uint32"
    panel = layout["configById"]["3D!attitude"]
    for topic in panel["topics"]:
        assert topic in schemas and schemas[topic][0] == "geometry_msgs/msg/TransformStamped", topic
