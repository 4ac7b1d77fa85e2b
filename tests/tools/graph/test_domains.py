"""Which ROS domain ``sappc run`` and the test suite use (docs/domains.md).

- ``sappc run``: ``--domain-id``, else ``ROS_DOMAIN_ID`` (the ROS convention), else the first
  free id of ``SAPPC_DOMAIN_IDS`` (default 1-101), claimed with a lock file whichever it is;
- the suite keeps off the user's ``ROS_DOMAIN_ID``: it is removed from the environment the tests
  and their processes see and taken out of the ids they claim from.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from gnc_common.validation import ConfigError
from sappc.graph.launch import DOMAIN_IDS, DOMAIN_IDS_ENV, claim_domain_id, domain_ids, format_domain_ids, requested_domain_id

from conftest import ROOT, SAPPC, SCENARIOS, keep_off_the_users_domain

#: The variable through which the outer test tells the inner one which domain is the user's.
_USER_DOMAIN_PROBE = "SAPPC_TEST_EXPECT_USER_DOMAIN"


def test_domain_ids_come_from_one_setting() -> None:
    assert domain_ids({}) == list(DOMAIN_IDS) == list(range(1, 102))
    assert domain_ids({DOMAIN_IDS_ENV: ""}) == list(DOMAIN_IDS)
    assert domain_ids({DOMAIN_IDS_ENV: "7"}) == [7]
    assert domain_ids({DOMAIN_IDS_ENV: "10-12, 3,11"}) == [10, 11, 12, 3]
    assert format_domain_ids([5, 1, 2, 3, 9, 10]) == "1-3,5,9-10"
    assert domain_ids({DOMAIN_IDS_ENV: format_domain_ids([5, 1, 2, 3, 9, 10])}) == [1, 2, 3, 5, 9, 10]


@pytest.mark.parametrize(("value", "message"), [
    ("abc", "SAPPC_DOMAIN_IDS: 'abc' is not a ROS domain id"),
    ("1-x", "SAPPC_DOMAIN_IDS: 'x' is not a ROS domain id"),
    ("300", "SAPPC_DOMAIN_IDS: domain id 300 is outside 0 to 232"),
    ("9-4", "SAPPC_DOMAIN_IDS: range '9-4' ends before it starts"),
    ("1,,2", "SAPPC_DOMAIN_IDS: '' is not a ROS domain id"),
])
def test_a_bad_domain_setting_is_one_line_naming_the_value(value: str, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        domain_ids({DOMAIN_IDS_ENV: value})
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


def test_the_requested_domain_is_the_option_then_ros_domain_id_then_a_claim() -> None:
    assert requested_domain_id(12, {"ROS_DOMAIN_ID": "30"}) == (12, "--domain-id")
    assert requested_domain_id(None, {"ROS_DOMAIN_ID": "30"}) == (30, "ROS_DOMAIN_ID")
    assert requested_domain_id(None, {"ROS_DOMAIN_ID": ""})[0] is None
    assert requested_domain_id(None, {})[0] is None
    with pytest.raises(ConfigError, match="ROS_DOMAIN_ID: 'robot' is not a ROS domain id"):
        requested_domain_id(None, {"ROS_DOMAIN_ID": "robot"})
    with pytest.raises(ConfigError, match="--domain-id: domain id 999 is outside 0 to 232"):
        requested_domain_id(999, {})


def test_the_suite_keeps_off_the_users_domain() -> None:
    env = {"ROS_DOMAIN_ID": "42", "PATH": "/bin"}
    assert keep_off_the_users_domain(env) == 42
    assert "ROS_DOMAIN_ID" not in env and 42 not in domain_ids(env) and len(domain_ids(env)) == len(DOMAIN_IDS) - 1
    env = {"ROS_DOMAIN_ID": "5", DOMAIN_IDS_ENV: "4-6"}
    assert keep_off_the_users_domain(env) == 5 and env == {DOMAIN_IDS_ENV: "4,6"}
    env = {DOMAIN_IDS_ENV: "4-6"}
    assert keep_off_the_users_domain(env) is None and env == {DOMAIN_IDS_ENV: "4-6"}


def _sappc_run_on_a_held_domain(tmp_path, env_overrides: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:  # type: ignore[no-untyped-def]
    env = {k: v for k, v in os.environ.items() if k not in ("ROS_DOMAIN_ID", DOMAIN_IDS_ENV)}
    env.update(env_overrides)
    return subprocess.run([*SAPPC, "run", str(SCENARIOS / "paper_tracking.yaml"), "--out", str(tmp_path / "run"), *args],
                          capture_output=True, text=True, env=env, cwd=ROOT, timeout=300)


@pytest.mark.slow
def test_sappc_run_uses_the_domain_id_option_then_ros_domain_id_then_its_setting(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Each source names a domain this test holds: ``sappc run`` tries exactly that one (and says
    which source named it), so it stops before starting any node, exit status 2."""
    with claim_domain_id() as held, claim_domain_id() as other:
        cases = [
            ({"ROS_DOMAIN_ID": str(other)}, ["--domain-id", str(held)], f"--domain-id: ROS domain {held} is in use"),
            ({"ROS_DOMAIN_ID": str(held)}, [], f"ROS_DOMAIN_ID: ROS domain {held} is in use"),
            ({DOMAIN_IDS_ENV: f"{held},{other}"}, [], f"no free ROS domain id among {DOMAIN_IDS_ENV}={format_domain_ids([held, other])}"),
        ]
        for env, args, said in cases:
            proc = _sappc_run_on_a_held_domain(tmp_path, env, *args)
            assert proc.returncode == 2 and said in proc.stderr, (env, args, proc.stdout + proc.stderr)
            assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
            assert not (tmp_path / "run").exists()  # nothing started, no run directory


@pytest.mark.slow
def test_the_suite_started_with_ros_domain_id_hides_it_from_its_processes(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The suite started by a user whose shell sets ``ROS_DOMAIN_ID`` (their other ROS work): the
    inner test below, run by a pytest of its own, sees no ``ROS_DOMAIN_ID``, nor do the processes
    it starts, and the ids they claim from exclude the user's."""
    env = {k: v for k, v in os.environ.items() if k != DOMAIN_IDS_ENV}
    env.update(ROS_DOMAIN_ID="7", **{DOMAIN_IDS_ENV: "6-8", _USER_DOMAIN_PROBE: "7"})
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           f"{__file__}::test_inner_the_users_domain_is_out_of_reach"], capture_output=True, text=True, env=env, cwd=ROOT,
                          timeout=300)
    assert proc.returncode == 0 and "1 passed" in proc.stdout, proc.stdout + proc.stderr


@pytest.mark.skipif(_USER_DOMAIN_PROBE not in os.environ, reason="run by test_the_suite_started_with_ros_domain_id_hides_it_from_its_processes")
def test_inner_the_users_domain_is_out_of_reach() -> None:
    user = int(os.environ[_USER_DOMAIN_PROBE])
    assert "ROS_DOMAIN_ID" not in os.environ
    assert user not in domain_ids() and domain_ids() == [6, 8]
    child = subprocess.run([sys.executable, "-c", "import os; from sappc.graph.launch import domain_ids, requested_domain_id; "
                            "print(os.environ.get('ROS_DOMAIN_ID'), requested_domain_id(None)[0], domain_ids())"],
                           capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert child.stdout.split() == ["None", "None", "[6,", "8]"], child.stdout + child.stderr
