"""The flight-mode kernel (issue 49, :mod:`sappc_modes.core.modes`): each guard at its threshold and
its persistence, the SAFE guards' precedence, the ground's requests and inhibits, unknown inputs,
compiled against interpreted, and the configuration's checks."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from gnc_common.validation import ConfigError
from sappc_modes.core import modes as m

DT = 0.1  # [s]
CONFIG = m.ModeConfig(detumbled_rate_rad_s=0.01, detumbled_for_s=1.0, converged_sigma_rad=1e-4, healthy_for_s=0.5,
                      safe_on_error_for_s=0.3, recover_for_s=2.0, max_wheel_speed_fraction=0.9)
PARAMS = CONFIG.packed(DT)  # persistences: 10, 5, 3, 20 samples
STEPS = [pytest.param(m.mode_step, id="compiled"), pytest.param(m.mode_step.py_func, id="interpreted")]


def sample(rate: float = math.nan, health: float = math.nan, sigma: float = math.nan, lost: float = 0.0, wheel: float = math.nan,
           request: float = -1.0, inhibit: float = 0.0, error: float = math.nan) -> np.ndarray:
    x = np.empty(m.N_INPUTS)
    x[m.IN_RATE], x[m.IN_HEALTH], x[m.IN_SIGMA], x[m.IN_LOST] = rate, health, sigma, lost
    x[m.IN_WHEEL], x[m.IN_REQUEST], x[m.IN_INHIBIT], x[m.IN_ERROR] = wheel, request, inhibit, error
    return x


#: A sample every guard toward TRACK accepts: slow, health OK, converged, nothing beyond a limit.
GOOD: dict[str, float] = {"rate": 0.001, "health": m.HEALTH_OK, "sigma": 5e-5, "wheel": 0.5}


def run(step: Any, state: np.ndarray, x: np.ndarray, n: int) -> list[int]:
    """``n`` samples of the inputs ``x``: each one's reason."""
    return [int(step(state, x, PARAMS)) for _ in range(n)]


def at(mode: int) -> np.ndarray:
    return m.new_mode_state(mode)


def test_persistences_are_whole_samples() -> None:
    """samples_for: ceil(seconds / dt), at least one; a quotient at an integer is that integer."""
    assert [m.samples_for(s, 0.1) for s in (0.0, 0.05, 0.1, 0.3, 0.31, 1.0, 30.0)] == [1, 1, 1, 3, 4, 10, 300]
    assert list(PARAMS[[m.P_RATE_N, m.P_HEALTHY_N, m.P_ERROR_N, m.P_RECOVER_N]]) == [10, 5, 3, 20]


@pytest.mark.parametrize("step", STEPS)
def test_detumble_ends_once_the_rate_stays_below_its_threshold_for_its_persistence(step: Any) -> None:
    state = at(m.DETUMBLE)
    assert run(step, state, sample(rate=0.01), 50) == [m.R_NONE] * 50  # at the threshold is not below it
    below = sample(rate=float(np.nextafter(0.01, 0.0)))
    assert run(step, state, below, 9) == [m.R_NONE] * 9
    assert run(step, state, sample(rate=0.02), 1) == [m.R_NONE]  # one fast sample restarts the count
    assert run(step, state, below, 9) == [m.R_NONE] * 9
    assert run(step, state, below, 1) == [m.R_DETUMBLED]
    assert state[m.S_MODE] == m.HOLD and state[m.S_REASON] == m.R_DETUMBLED


@pytest.mark.parametrize("step", STEPS)
def test_detumble_ignores_the_estimator_and_the_wheels(step: Any) -> None:
    """While tumbling the tracker cannot lock: ERROR, loss of control or fast wheels send DETUMBLE nowhere."""
    state = at(m.DETUMBLE)
    assert run(step, state, sample(rate=1.0, health=m.HEALTH_ERROR, lost=1.0, wheel=5.0), 100) == [m.R_NONE] * 100
    assert state[m.S_MODE] == m.DETUMBLE


@pytest.mark.parametrize("step", STEPS)
def test_hold_tracks_once_healthy_and_converged_for_its_persistence(step: Any) -> None:
    state = at(m.HOLD)
    assert run(step, state, sample(**{**GOOD, "sigma": 1.0000001e-4}), 20) == [m.R_NONE] * 20  # not converged
    assert run(step, state, sample(**{**GOOD, "health": m.HEALTH_WARN}), 20) == [m.R_NONE] * 20  # WARN is not OK
    assert run(step, state, sample(**{**GOOD, "sigma": 1e-4}), 4) == [m.R_NONE] * 4  # at the threshold: converged
    assert run(step, state, sample(**GOOD), 1) == [m.R_ACQUIRED]
    assert state[m.S_MODE] == m.TRACK


@pytest.mark.parametrize("step", STEPS)
@pytest.mark.parametrize("mode", [m.HOLD, m.TRACK])
@pytest.mark.parametrize(("bad", "n", "reason"), [({"lost": 1.0}, 1, m.R_CONTROL_LOST),
                                                  ({"wheel": float(np.nextafter(0.9, 1.0))}, 1, m.R_WHEEL_SPEED),
                                                  ({"health": m.HEALTH_ERROR}, 3, m.R_ESTIMATOR_ERROR),
                                                  ({"health": m.HEALTH_STALE}, 3, m.R_ESTIMATOR_ERROR)])
def test_hold_and_track_go_safe_on_each_safe_condition(step: Any, mode: int, bad: dict[str, float], n: int, reason: int) -> None:
    """Loss of control and a wheel beyond its fraction at once; ERROR or STALE after its persistence."""
    state = at(mode)
    assert run(step, state, sample(**{**GOOD, "wheel": 0.9}), 4) == [m.R_NONE] * 4  # at the wheel's fraction: not beyond
    state = at(mode)
    assert run(step, state, sample(**{**GOOD, **bad}), n) == [m.R_NONE] * (n - 1) + [reason]
    assert state[m.S_MODE] == m.SAFE


@pytest.mark.parametrize("step", STEPS)
def test_a_safe_condition_comes_before_tracking(step: Any) -> None:
    """HOLD, healthy long enough to track, meets a loss of control in the same sample: SAFE, not TRACK."""
    state = at(m.HOLD)
    run(step, state, sample(**GOOD), 4)
    assert run(step, state, sample(**{**GOOD, "lost": 1.0}), 1) == [m.R_CONTROL_LOST]


@pytest.mark.parametrize("step", STEPS)
def test_safe_recovers_to_hold_after_its_persistence_then_hold_waits_its_own(step: Any) -> None:
    state = at(m.SAFE)
    assert run(step, state, sample(**{**GOOD, "wheel": 0.95}), 40) == [m.R_NONE] * 40  # a wheel still beyond its fraction
    assert run(step, state, sample(**GOOD), 19) == [m.R_NONE] * 19
    assert run(step, state, sample(**GOOD), 1) == [m.R_RECOVERED]
    assert state[m.S_MODE] == m.HOLD
    assert run(step, state, sample(**GOOD), 5) == [m.R_NONE] * 4 + [m.R_ACQUIRED]  # HOLD's count starts at its entry


@pytest.mark.parametrize("step", STEPS)
def test_unknown_inputs_meet_no_condition(step: Any) -> None:
    """NaN (no measurement, no health message yet) starts no mode and sends none to SAFE."""
    for mode in (m.DETUMBLE, m.HOLD, m.TRACK, m.SAFE):
        state = at(mode)
        assert run(step, state, sample(lost=math.nan, request=math.nan, inhibit=math.nan), 100) == [m.R_NONE] * 100
        assert state[m.S_MODE] == mode


@pytest.mark.parametrize("step", STEPS)
def test_a_ground_request_goes_through_at_once_and_an_invalid_one_is_ignored(step: Any) -> None:
    state = at(m.DETUMBLE)
    for bad in (4.0, -2.0, 1.5, math.inf):
        assert run(step, state, sample(request=bad), 1) == [m.R_NONE]
    assert run(step, state, sample(request=m.DETUMBLE), 1) == [m.R_NONE]  # the current mode: no transition
    assert run(step, state, sample(request=m.TRACK, inhibit=15.0), 1) == [m.R_REQUEST]  # inhibits stop automatic ones only
    assert state[m.S_MODE] == m.TRACK and state[m.S_REASON] == m.R_REQUEST


@pytest.mark.parametrize("step", STEPS)
@pytest.mark.parametrize(("mode", "x", "flag", "reason"), [
    (m.DETUMBLE, {"rate": 0.001}, m.INHIBIT_DETUMBLED, m.R_DETUMBLED),
    (m.HOLD, GOOD, m.INHIBIT_ACQUIRED, m.R_ACQUIRED),
    (m.TRACK, {**GOOD, "lost": 1.0}, m.INHIBIT_SAFE, m.R_CONTROL_LOST),
    (m.SAFE, GOOD, m.INHIBIT_RECOVERED, m.R_RECOVERED),
])
def test_each_inhibit_stops_its_automatic_transition_only(step: Any, mode: int, x: dict[str, float], flag: int, reason: int) -> None:
    state = at(mode)
    others = 15 - flag
    assert run(step, state, sample(**x, inhibit=flag), 30) == [m.R_NONE] * 30
    state = at(mode)
    assert reason in run(step, state, sample(**x, inhibit=others), 30)


def test_compiled_and_interpreted_take_the_same_transitions_on_random_flights() -> None:
    """The node runs the source interpreted, loops run it compiled: the same reasons and states."""
    rng = np.random.default_rng(49)
    for _ in range(20):
        a, b = at(int(rng.integers(4))), None
        b = a.copy()
        for _ in range(400):
            x = sample(rate=float(rng.choice([0.005, 0.02, math.nan])), health=float(rng.choice([0, 0, 0, 1, 2, 3, math.nan])),
                       sigma=float(rng.choice([5e-5, 2e-4])), lost=float(rng.random() < 0.01), wheel=float(rng.choice([0.5, 0.95])),
                       request=float(rng.choice([-1.0] * 30 + [0.0, 1.0, 2.0, 3.0])), inhibit=float(rng.integers(0, 16) if rng.random() < 0.1 else 0))
            assert m.mode_step(a, x, PARAMS) == m.mode_step.py_func(b, x, PARAMS)
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(("name", "value"), [("detumbled_rate_rad_s", 0.0), ("detumbled_rate_rad_s", math.nan), ("converged_sigma_rad", -1.0),
                                             ("healthy_for_s", -0.1), ("recover_for_s", math.inf), ("max_wheel_speed_fraction", True),
                                             ("safe_on_error_for_s", [1.0, 2.0])])
def test_the_configuration_refuses_a_bad_value_naming_it(name: str, value: object) -> None:
    with pytest.raises(ConfigError, match=name):
        m.ModeConfig(**{name: value})  # type: ignore[arg-type]


def test_a_flight_starts_in_a_mode_of_the_four() -> None:
    assert m.new_mode_state()[m.S_MODE] == m.DETUMBLE and m.new_mode_state(m.SAFE)[m.S_MODE] == m.SAFE
    for bad in (4, -1, True):
        with pytest.raises(ConfigError, match="mode"):
            m.new_mode_state(bad)
    with pytest.raises(ConfigError, match="dt_s"):
        CONFIG.packed(0.0)


@pytest.mark.parametrize("step", STEPS)
def test_with_an_acquisition_threshold_hold_hands_over_only_near_the_reference(step: Any) -> None:
    """``acquired_error_rad``: HOLD -> TRACK also needs the error against the reference within it,
    every sample of ``healthy_for_s`` (at the threshold counts; NaN, unknown, does not); without
    it (default) the error is not read."""
    params = dataclasses.replace(CONFIG, acquired_error_rad=0.02).packed(DT)
    state = at(m.HOLD)
    for _ in range(20):  # healthy but far: never
        assert step(state, sample(**GOOD, error=0.5), params) == m.R_NONE
    for _ in range(20):  # healthy, the error unknown: never
        assert step(state, sample(**GOOD), params) == m.R_NONE
    reasons = [int(step(state, sample(**GOOD, error=0.02), params)) for _ in range(5)]
    assert reasons == [m.R_NONE] * 4 + [m.R_ACQUIRED]  # 0.5 s at 0.1 s: the 5th sample at the threshold
    state = at(m.HOLD)
    assert [int(step(state, sample(**GOOD, error=0.5), PARAMS)) for _ in range(5)] == [m.R_NONE] * 4 + [m.R_ACQUIRED]  # not read
    with pytest.raises(ConfigError, match="acquired_error_rad"):
        m.ModeConfig(acquired_error_rad=0.0)
    assert m.ModeConfig().packed(DT)[m.P_ACQUIRED] == math.inf


@pytest.mark.parametrize("step", STEPS)
def test_with_a_lost_attitude_threshold_track_goes_safe_after_its_persistence(step: Any) -> None:
    """``lost_error_rad``: TRACK -> SAFE (``control_lost``) once the estimate's error against the
    reference stays above it for ``lost_for_s`` (at the threshold is not above it; an unknown error,
    NaN, restarts the count); HOLD is not judged by it (an acquisition starts far); the SAFE inhibit
    stops it; without it (default) the error is not read."""
    params = dataclasses.replace(CONFIG, lost_error_rad=0.05, lost_for_s=0.3).packed(DT)  # 3 samples
    above = float(np.nextafter(0.05, 1.0))
    state = at(m.TRACK)
    assert [int(step(state, sample(**GOOD, error=0.05), params)) for _ in range(10)] == [m.R_NONE] * 10
    assert [int(step(state, sample(**GOOD, error=above), params)) for _ in range(2)] == [m.R_NONE] * 2
    assert step(state, sample(**GOOD), params) == m.R_NONE  # unknown: the count restarts
    assert [int(step(state, sample(**GOOD, error=above), params)) for _ in range(3)] == [m.R_NONE] * 2 + [m.R_CONTROL_LOST]
    assert state[m.S_MODE] == m.SAFE and state[m.S_LOST_N] == 0.0  # every count restarts at a transition
    state = at(m.HOLD)
    far = sample(**GOOD, error=1.0)
    assert [int(step(state, far, params)) for _ in range(5)] == [m.R_NONE] * 4 + [m.R_ACQUIRED]  # HOLD: never SAFE on it, tracks
    state = at(m.TRACK)
    x = sample(**GOOD, error=1.0, inhibit=float(m.INHIBIT_SAFE))
    assert [int(step(state, x, params)) for _ in range(10)] == [m.R_NONE] * 10
    state = at(m.TRACK)
    assert [int(step(state, sample(**GOOD, error=1.0), PARAMS)) for _ in range(10)] == [m.R_NONE] * 10  # not read
    with pytest.raises(ConfigError, match="lost_error_rad"):
        m.ModeConfig(lost_error_rad=-1.0)
    assert m.ModeConfig().packed(DT)[m.P_LOST] == math.inf and list(PARAMS[[m.P_LOST_N]]) == [100]
