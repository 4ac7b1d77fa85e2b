"""The reaction wheels in a bag's report, on synthetic bags (``mcap``'s writer, rclpy's serializer):
``joint_states`` paired with the states by stamp into the History (NaN before the first message),
the wheel metrics, and ``wheels.png`` drawn with the limits of the scenario embedded in the bag;
a bag of the ideal actuator has neither, and no note about ``joint_states``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from bagmaker import write_bag

from sappc.analysis.report import analyse_bag, write_report
from sappc.bag.read import SCENARIO_RECORD
from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import joint_state_msg, quaternion_msg, torque_msg, vector3_msg

from conftest import SCENARIOS
from figure_checks import NO_EMPTY_LOG_AXES, assert_every_axes_shows_data, capture_figures

pytestmark = NO_EMPTY_LOG_AXES  # the report draws its figures in this process


def _bag(path: Path, scenario: str, speeds: np.ndarray | None, torques: np.ndarray | None, first_wheels: int = 0) -> Path:
    """100 samples at 100 Hz of a body at rest on the identity reference; wheel records from
    sample ``first_wheels`` on (when given)."""
    messages = []
    for k in range(100):
        ts = 1.0 + 0.01 * k  # stamps need not start at 0
        messages += [
            (c.STATE_ATTITUDE.name, c.STATE_ATTITUDE.type_name, quaternion_msg([0.0, 0.0, 0.0, 1.0], ts, c.STATE_ATTITUDE), k),
            (c.STATE_RATE.name, c.STATE_RATE.type_name, vector3_msg([0.0, 0.0, 0.0], ts, c.STATE_RATE), k),
            (c.REFERENCE_ATTITUDE.name, c.REFERENCE_ATTITUDE.type_name, quaternion_msg([0.0, 0.0, 0.0, 1.0], ts, c.REFERENCE_ATTITUDE), k),
            (c.CONTROL_TORQUE.name, c.CONTROL_TORQUE.type_name, torque_msg([0.01, 0.0, -0.02], ts, c.CONTROL_TORQUE), k),
        ]
        if speeds is not None and torques is not None and k >= first_wheels:
            messages.append((c.WHEEL_STATES.name, c.WHEEL_STATES.type_name, joint_state_msg(speeds[k], torques[k], ts), k))
    return write_bag(path, messages, metadata={SCENARIO_RECORD: {"text": scenario}})


def test_a_bag_with_wheels_reports_their_records_metrics_and_figure(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """(The body rests on the reference: |q_ev| is exactly zero, and the bag has no performance
    function, so the log figure has nothing positive to draw: it stays linear and says so, rather
    than an empty log axes, issue 25, 2.5.)"""
    figures = capture_figures(monkeypatch)
    text = (SCENARIOS / "paper_tracking_wheels.yaml").read_text()
    rng = np.random.default_rng(16)
    speeds, torques = 600.0 * rng.uniform(-1, 1, (100, 4)), 0.2 * rng.uniform(-1, 1, (100, 4))
    a = analyse_bag(_bag(tmp_path / "w.mcap", text, speeds, torques, first_wheels=3))
    h = a.run.history
    assert h.wheel_speed_rad_s is not None and h.wheel_torque_Nm is not None
    assert h.wheel_speed_rad_s.shape == h.wheel_torque_Nm.shape == (100, 1, 4)
    assert np.isnan(h.wheel_speed_rad_s[:3]).all() and np.isnan(h.wheel_torque_Nm[:3]).all()  # before the first message
    assert np.array_equal(h.wheel_speed_rad_s[3:, 0], speeds[3:]) and np.array_equal(h.wheel_torque_Nm[3:, 0], torques[3:])
    assert a.metrics["max_abs_wheel_speed_rad_s"] == np.abs(speeds[3:]).max()
    assert a.metrics["max_abs_wheel_torque_Nm"] == np.abs(torques[3:]).max()
    assert not any("joint_states" in n for n in a.notes), a.notes
    written = write_report(a, tmp_path / "report")
    assert tmp_path / "report" / "wheels.png" in written and (tmp_path / "report" / "wheels.png").stat().st_size > 10_000
    # the bag has no controller diagnostics: no transformed error nor Lyapunov values to draw
    assert_every_axes_shows_data(figures, empty_ok=lambda title, ax: "Lyapunov" in title)
    log = next(f for f in figures if "magnitude" in f._suptitle.get_text())
    assert all(ax.get_yscale() == "linear" and "no positive value" in ax.texts[0].get_text() for ax in log.axes)


def test_a_bag_of_the_ideal_actuator_has_no_wheels(tmp_path: Path) -> None:
    ideal = (SCENARIOS / "paper_tracking.yaml").read_text()
    a = analyse_bag(_bag(tmp_path / "i.mcap", ideal, None, None))
    assert a.run.history.wheel_speed_rad_s is None and "max_abs_wheel_speed_rad_s" not in a.metrics
    assert not any("joint_states" in n for n in a.notes), a.notes  # nobody publishes it: not missing
    # a wheel scenario whose bag lacks the wheels says so
    raw = yaml.safe_load((SCENARIOS / "paper_tracking_wheels.yaml").read_text())
    a = analyse_bag(_bag(tmp_path / "m.mcap", yaml.safe_dump(raw), None, None))
    assert any("absent" in n and "joint_states" in n for n in a.notes), a.notes
