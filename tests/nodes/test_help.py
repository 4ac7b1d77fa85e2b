"""``python -m <node> --help`` lists the parameters each node declares, from the same records
(:mod:`sappc_msgs_py.parameters`): a parameter the node declares but the help omits, or the
reverse, fails here."""

from __future__ import annotations

import subprocess
import sys

import pytest
from rclpy.parameter import Parameter

from conftest import ROOT

#: Parameters rclpy declares on every node by itself.
RCLPY_OWN = {"use_sim_time", "start_type_description_service"}
#: module, class of every node run with ``python -m``.
NODES = {
    "sappc_controller": ("sappc_controller.node", "ControllerNode"),
    "sappc_estimator": ("sappc_estimator.node", "EstimatorNode"),
    "sappc_momentum": ("sappc_momentum.node", "MomentumNode"),
    "sappc_modes": ("sappc_modes.node", "ModeNode"),
    "spacecraft_sim": ("spacecraft_sim.plant_node", "PlantNode"),
    "spacecraft_sim.reference": ("spacecraft_sim.reference", "ReferenceNode"),
    "spacecraft_sim.disturbance": ("spacecraft_sim.disturbance", "InjectorNode"),
    "sappc.graph.recorder": ("sappc.graph.recorder", "RecorderNode"),
}


def _node_class(module: str, name: str):  # type: ignore[no-untyped-def]
    import importlib

    return getattr(importlib.import_module(module), name)


@pytest.mark.parametrize("command", sorted(NODES))
def test_help_lists_every_parameter_and_exits_0_without_ros(command: str) -> None:
    proc = subprocess.run([sys.executable, "-m", command, "--help"], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    cls = _node_class(*NODES[command])
    params = [p for _, section in cls.parameter_sections() for p in section]
    assert len(params) >= 4
    lines = proc.stdout.splitlines()
    assert lines[0].startswith(f"usage: python -m {command} ")
    for p in params:  # its line: name, type, unit, default, then the description on the next line
        i = next(i for i, ln in enumerate(lines) if ln.startswith(f"  {p.name}  ("))
        assert p.type in lines[i] and "default " in lines[i] and (not p.unit or f"[{p.unit}]" in lines[i]), lines[i]
        assert lines[i + 1].strip(), f"{p.name} has no description"


def test_the_estimators_help_lists_the_filters_parameters_from_its_config() -> None:
    """Every field of MekfConfig is a parameter, with its unit, its rule and the config's own description."""
    import dataclasses

    from sappc_estimator.core.config import MekfConfig
    from sappc_estimator.node import EstimatorNode

    text = EstimatorNode.help_text()
    assert [p.name for p in EstimatorNode.parameter_sections()[1][1]] == [f.name for f in dataclasses.fields(MekfConfig)]
    assert "  tracker_noise_rad  (double[]; [rad]; default (required); must be > 0 per axis)" in text
    assert "  initial_q_BN  (double[]; default []; must be [] or a unit quaternion (x, y, z, w))" in text
    assert "  max_consecutive_rejections  (integer; default 20; must be an integer >= 1)" in text
    assert "  max_stamp_ahead_s  (double; [s]; default 1; range [1e-06, 3600])" in text
    assert "``" not in text and "changeable at run time" not in text  # read at start-up


def test_the_controllers_help_states_types_units_ranges_and_what_changes_at_run_time() -> None:
    from sappc_controller.node import ControllerNode

    text = ControllerNode.help_text()
    assert "  stale_timeout_s  (double; [s]; default 0.1; range [1e-06, 3600]; changeable at run time)" in text
    assert "  sappc.gains.D_m_Nm  (double; [N m]; default (required); range [0, 1e+06]; changeable at run time)" in text
    assert "  sappc.rpf.l  (double; [1/s]; default (required); range [0, 1e+06])" in text  # fixed during a run
    assert "  blfppc.ftppf.m_odd  (integer; default 1; range [1, 99])" in text
    assert "  controller  (string; default 'sappc'; one of sappc, trappc, blfppc, mrp_feedback)" in text
    assert "  mrp_feedback.gains.Ki_per_kg_m2  (double; [1/(kg m^2)]; default 0; range [0, 1e+06]; changeable at run time)" in text
    assert "``" not in text  # reStructuredText markup is shown as plain text


@pytest.mark.parametrize("command", sorted(NODES))
def test_a_node_declares_exactly_what_its_help_lists(command: str, ros_context, tmp_path) -> None:  # type: ignore[no-untyped-def]
    cls = _node_class(*NODES[command])
    overrides: list[Parameter] = []
    if command == "sappc_controller":
        from test_nodes import _controller_overrides

        overrides = _controller_overrides()
    elif command == "sappc_estimator":
        from test_estimator_node import overrides as estimator_overrides

        overrides = estimator_overrides()
    elif command == "sappc_momentum":
        from test_momentum_node import overrides as momentum_overrides

        overrides = momentum_overrides()
    elif command == "sappc_modes":
        from test_mode_node import overrides as mode_overrides

        overrides = mode_overrides()
    elif command == "sappc.graph.recorder":
        overrides = [Parameter("output_dir", value=str(tmp_path / "bag"))]
    node = cls(context=ros_context, parameter_overrides=overrides)
    try:
        declared = set(node._parameters) - RCLPY_OWN
        sections = cls.parameter_sections()
        if command == "sappc_controller":  # the law's section of the kind it runs, not the others'
            sections = [(t, s) for t, s in sections if "law" not in t or "controller: sappc" in t]
        listed = {p.name for _, section in sections for p in section}
        assert declared == listed, (declared - listed, listed - declared)
        for _, section in sections:  # the descriptor rclpy enforces and tools show is the record's
            for p in section:
                d = node.describe_parameter(p.name)
                assert d.read_only == p.read_only, p.name
                if p.unit:
                    assert d.description.startswith(f"[{p.unit}] "), (p.name, d.description)
                if p.range is not None and p.type == "double":
                    assert (d.floating_point_range[0].from_value, d.floating_point_range[0].to_value) == p.range, p.name
    finally:
        node.destroy_node()


def test_help_into_a_closed_pipe_is_no_error() -> None:
    """``python -m sappc_controller --help | head -1``: the reader has gone before the help is
    written (here for certain: the pipe's read end is closed before the node starts); the help ends
    quietly with status 0, not a BrokenPipeError traceback."""
    import os
    import subprocess
    import sys

    read_end, write_end = os.pipe()
    os.close(read_end)  # every write to the pipe now fails with EPIPE
    try:
        proc = subprocess.run([sys.executable, "-m", "sappc_controller", "--help"], stdout=write_end, stderr=subprocess.PIPE,
                              text=True, timeout=120)
    finally:
        os.close(write_end)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr and "BrokenPipeError" not in proc.stderr, proc.stderr
