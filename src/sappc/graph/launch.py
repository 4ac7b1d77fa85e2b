"""The entry script of ``sappc run``: a whole experiment through real ROS 2 processes.

``run_graph`` turns a scenario into node parameters, starts each node as its own process on an
isolated domain (recorder, controller, reference, injector, plant), lets the plant run the
scenario to its end (lockstep) or for its duration (real time), stops the others with SIGINT in
an order that loses no message (publishers first, they wait for acknowledgements; the recorder
last, it drains its queues), checks that the bag holds exactly what was published, and computes
the same metrics as ``sappc simulate`` from the bag.

Isolation (docs/ros2_notes.md, docs/domains.md): a ``ROS_DOMAIN_ID`` (``--domain-id``, else the
environment's ``ROS_DOMAIN_ID``, else the first free id of :data:`DOMAIN_IDS_ENV`) claimed with a
lock file (two runs at once never share a domain), ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, the project's Fast DDS profile for
fast discovery, ``ROS_LOG_DIR`` inside the run directory.  No process outlives the run: every
child is waited for, killed after :data:`STOP_TIMEOUT_S` if it must be, and stale Fast DDS
shared-memory segments are cleaned when one had to be killed.

Bring-up (issue 49, item 2; docs/how-to/nodes.md, "Bring-up: managed nodes"): the controller, and
the estimator, mode and momentum nodes of a scenario that has them (:data:`MANAGED_NODES`), are
started as ROS 2 managed (lifecycle) nodes: ``-p managed:=true`` on their command line (in the
composed process, in their arguments), not in ``params.yaml``, which stays the plain nodes' file
(with it alone each node starts configured and active, as ``python -m sappc_controller`` does by
default).  They start ``unconfigured``, and the launcher brings them up through the standard
lifecycle services with a plain rclpy client of ``lifecycle_msgs`` in its own process
(:class:`_BringUp`: a context of its own on the run's domain, with the nodes' discovery range and
Fast DDS profile, no signal handlers): ``configure`` each (``/<node>/change_state``), in the order
estimator, modes, controller, momentum (those the run has), then ``activate`` each in the same
order, one transition at a time, each answered before the next is asked.  Meanwhile the other
processes start and wait for their partners as always; what they wait for is made at configure
(the managed nodes' subscriptions and publishers: the plant waits for a publisher of its torque
and for its expected subscribers, the recorder for every publisher of what it records before it
subscribes to ``/clock``), so nothing waited for is missing for good while a node is unconfigured,
and none of them gives up waiting (no time limit on those waits; the run's own stall rule and
deadline apply).  Configured is not yet active: the plant's first sample waits for one subscriber
more, the client's ``state/tf`` subscription, made once every managed node is active (the plant's
``expected_subscribers`` count it), so no sample is ever answered by an inactive node and the
lockstep samples are exactly those of plain nodes.  Once the plant's first sample has come
through, the client lets go (its subscription, node and context).  A transition a node answers
with ``success: false`` (a parameter its configure refuses) stops the run with one line naming the
node and the transition, followed by that node's last log lines (the composed process's when
composed), as a node that fails to start does (``RuntimeError``; ``sappc run``: exit status 1).
``logs/bringup.json`` (:data:`BRINGUP_FILE`) records every transition: the node, its label, when it
was asked and answered (CLOCK_MONOTONIC seconds, the clock of the plant's ``logs/timing.json``),
when every node was active and when the plant's first sample came through.  With ``--plant
external`` there is no gate (your plant is told to start once the nodes are active).
"""

from __future__ import annotations

import contextlib
import fcntl
from collections import Counter
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, cast

import numpy as np
import yaml

from sappc_msgs_py.runtime import parse_expected, write_json_whole
from sappc_estimator.params import parameters_from_config as estimator_parameters_from_config
from sappc_modes.core.modes import MODE_NAMES
from sappc_msgs_py.contract import (CLOCK, CONTROL_DIPOLE, CONTROL_TORQUE, CONTROL_WHEEL_TORQUE, ESTIMATOR_COVARIANCE, ESTIMATOR_DIAGNOSTICS,
                                    ESTIMATOR_HEALTH,
                                    MODE_STATUS, REFERENCE_ATTITUDE, RELAYED_REFERENCE_TOPICS, SENSOR_GYRO, STATE_MAGNETIC_FIELD, STATE_WHEEL_SPEED,
                                    TRUTH_MAGNETIC_FIELD, ESTIMATOR_TOPICS, FAULT_TOPICS, RELAYED_ACTUATOR_TOPICS,
                                    RELAYED_PATHS, RELAYED_SENSOR_TOPICS, RELAYED_SENSOR_TOPICS_FOR_ESTIMATOR, STATE_ATTITUDE,
                                    STATE_RATE, TOPICS, controller_state_sources, faulty, relay_remaps)
from spacecraft_sim.core.faults import FaultSchedule
from spacecraft_sim.core.wheels import allocation_matrix
from gnc_common.validation import ConfigError, safe_load_yaml

from sappc.bag.read import Ticker
from sappc.files import default_output_dir, scenario_path as bundled_scenario_path
from sappc.graph.container import NODE_CLASSES, STOP_ORDER
from sappc.scenario import EXTENDS_KEY, ControllerKind, Scenario, controller_node_parameters, load_scenario

__all__ = ["DOMAIN_IDS_ENV", "RT_PRIORITIES", "GraphResult", "check_rt_priority", "claim_domain_id", "domain_ids", "format_domain_ids",
           "isolated_environment", "node_parameters", "requested_domain_id", "run_graph"]

#: How long a node may take to stop after SIGINT before it is killed [s]; for the recorder (and the
#: composed process, which holds it), how long it may go without writing to its bag: closing a
#: long run's bag (writing what it took, then the sort) takes longer than this, and is progress.
STOP_TIMEOUT_S = 15.0
#: Period of the stop's check for progress [s].
STOP_CHECK_S = 1.0
#: The environment variable that sets the domain ids ``sappc run`` and the test suite claim from
#: (:func:`domain_ids`): comma-separated ids and inclusive ranges, e.g. ``1-41,43-101``.
DOMAIN_IDS_ENV = "SAPPC_DOMAIN_IDS"
#: The domain ids claimed when :data:`DOMAIN_IDS_ENV` is not set (0 is everyone's default; ids
#: above 101 collide with ephemeral ports on Linux, ROS 2's "choosing a domain ID" page).
DOMAIN_IDS = range(1, 102)
#: The largest domain id ROS 2 accepts with Fast DDS (its port formula, 7400 + 250 id + offsets,
#: must stay below 65536); ids above 101 are accepted but may collide with ephemeral ports.
MAX_DOMAIN_ID = 232
#: The nodes of a run, in start order (the plant starts last: it owns time).
NODES = ("recorder", "estimator", "modes", "controller", "momentum", "reference", "injector", "plant")
#: The nodes ``sappc run`` starts as ROS 2 managed (lifecycle) nodes (``managed:=true``), in the
#: order it configures them, then activates them (module docstring, "Bring-up"); a run has those
#: its scenario needs (always the controller).
MANAGED_NODES = ("estimator", "modes", "controller", "momentum")
#: The bring-up's transitions (``lifecycle_msgs/msg/Transition``'s labels), each made for every
#: managed node of the run, in :data:`MANAGED_NODES` order, before the next.
BRINGUP_TRANSITIONS = ("configure", "activate")
#: The bring-up's record (in the run directory): every transition's node, label, request and
#: answer times (CLOCK_MONOTONIC [s], the clock of the plant's timing file) and the gate's opening.
BRINGUP_FILE = "logs/bringup.json"
#: Plants of ``sappc run --plant``: the bundled rigid body (``python -m spacecraft_sim``), or the
#: user's own, started separately (every node but the plant is started; the run ends once the
#: torque of the scenario's last sample is recorded, or on Ctrl-C).
PLANTS = ("native", "basilisk", "external")
#: The file the recorder writes when an external plant's run has reached its end (in the run directory).
END_FILE = "end_reached"
#: The recorder's progress file (in the run directory), which ``sappc run``'s progress line reads.
PROGRESS_FILE = "logs/progress.json"
#: ``--live``: where the recorder writes the live view's address, where ``sappc run`` writes the
#: run's verdict for the view, and the file the recorder writes once its bag is closed and it
#: waits for that verdict (in the run directory; :mod:`sappc.graph.recorder`, "Live view").
LIVE_FILE = "logs/live.json"
LIVE_VERDICT_FILE = "logs/live_verdict.json"
LIVE_WAITING_FILE = "logs/live_verdict.json.wait"
#: Period of ``sappc run``'s progress line [s]: at least one every 2 s (issue 37), from the
#: recorder's file, which it rewrites at each flush (0.5 s).
PROGRESS_PERIOD_S = 1.0
#: Lockstep without ``timeout_s``: the run fails when no new sample is recorded for this long [s]
#: (a lockstep run has no wall-clock pace: a loaded machine may fly an orbit slower than real time,
#: measured 75 to 180 samples/s for a 100 Hz scenario; a stall is what must stop it), the first
#: sample included (the nodes start in ~10 s, ~60 s on a loaded machine).
LOCKSTEP_STALL_S = 300.0
#: And once the last sample is in, the nodes stop and the recorder closes the bag within this much
#: plus :data:`CLOSE_S_PER_SAMPLE` a sample recorded [s] (a safety net for a hung close: sorting
#: one orbit's 800 MB bag took 15 min on a loaded 2-core machine, 1.6 ms a sample).
CLOSE_BASE_S = 60.0
CLOSE_S_PER_SAMPLE = 5e-3


def fastdds_profile() -> Path:
    """The project's Fast DDS profile (fast discovery on one host)."""
    return Path(str(resources.files("sappc.graph") / "fastdds_profile.xml"))


def _domain_id(text: str, source: str) -> int:
    """One domain id from ``source`` (a setting's name, for the error)."""
    try:
        value = int(text.strip())
    except ValueError:
        raise ConfigError(f"{source}: {text.strip()!r} is not a ROS domain id (an integer 0 to {MAX_DOMAIN_ID})") from None
    if not 0 <= value <= MAX_DOMAIN_ID:
        raise ConfigError(f"{source}: domain id {value} is outside 0 to {MAX_DOMAIN_ID}")
    return value


def domain_ids(environ: Mapping[str, str] | None = None) -> list[int]:
    """The domain ids to claim from: :data:`DOMAIN_IDS_ENV` (``"1-41,43-101"``: ids and inclusive
    ranges, in the order given) or, when it is unset or empty, :data:`DOMAIN_IDS`.

    Raises
    ------
    ConfigError
        Naming the setting and the offending entry (not an integer, outside 0 to
        :data:`MAX_DOMAIN_ID`, a reversed range, no id at all).
    """
    text = (os.environ if environ is None else environ).get(DOMAIN_IDS_ENV, "").strip()
    if not text:
        return list(DOMAIN_IDS)
    ids: list[int] = []
    for entry in text.split(","):
        low, sep, high = entry.partition("-")
        if not sep:
            ids.append(_domain_id(entry, DOMAIN_IDS_ENV))
            continue
        first, last = _domain_id(low, DOMAIN_IDS_ENV), _domain_id(high, DOMAIN_IDS_ENV)
        if last < first:
            raise ConfigError(f"{DOMAIN_IDS_ENV}: range {entry.strip()!r} ends before it starts")
        ids.extend(range(first, last + 1))
    return list(dict.fromkeys(ids))


def format_domain_ids(ids: Iterable[int]) -> str:
    """``ids`` as a :data:`DOMAIN_IDS_ENV` value (sorted, runs as ranges): ``[1, 2, 3, 5]`` -> ``"1-3,5"``."""
    runs: list[list[int]] = []
    for i in sorted(set(ids)):
        if runs and i == runs[-1][1] + 1:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    return ",".join(f"{a}" if a == b else f"{a}-{b}" for a, b in runs)


def requested_domain_id(domain_id: int | None, environ: Mapping[str, str] | None = None) -> tuple[int | None, str]:
    """The domain a run was asked to use, and who asked: ``domain_id`` (``--domain-id``), else
    ``ROS_DOMAIN_ID`` from ``environ`` (the ROS convention), else ``(None, ...)``: claim a free
    one among :func:`domain_ids`.

    Raises
    ------
    ConfigError
        For an id (from either source) that is not an integer 0 to :data:`MAX_DOMAIN_ID`.
    """
    if domain_id is not None:
        return _domain_id(str(domain_id), "--domain-id"), "--domain-id"
    env = os.environ if environ is None else environ
    if env.get("ROS_DOMAIN_ID", "").strip():
        return _domain_id(env["ROS_DOMAIN_ID"], "ROS_DOMAIN_ID"), "ROS_DOMAIN_ID"
    return None, f"the first free one of {DOMAIN_IDS_ENV}"


@contextlib.contextmanager
def claim_domain_id(preferred: int | None = None, *, source: str = "the domain id") -> Iterator[int]:
    """Hold a ROS domain id no other ``sappc`` run or test on this machine uses meanwhile:
    ``preferred``, or the first free one of :func:`domain_ids`.

    The claim is an exclusive ``flock`` on ``$TMPDIR/sappc-domain-<id>.lock``, released when the
    context ends (or the process dies).  ``source`` names where ``preferred`` came from, for the
    error.

    Raises
    ------
    ConfigError
        When ``preferred`` is held by another run, or every id of :func:`domain_ids` is.
    """
    candidates = [preferred] if preferred is not None else domain_ids()
    for domain in candidates:
        path = Path(tempfile.gettempdir()) / f"sappc-domain-{domain}.lock"
        fd = os.open(path, os.O_CREAT | os.O_RDWR, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            continue
        try:
            yield domain
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)
        return
    if preferred is not None:
        raise ConfigError(f"{source}: ROS domain {preferred} is in use by another sappc run or test on this machine "
                          f"(lock {Path(tempfile.gettempdir()) / f'sappc-domain-{preferred}.lock'}); choose another")
    raise ConfigError(f"no free ROS domain id among {DOMAIN_IDS_ENV}={format_domain_ids(candidates)}: every one is claimed by a "
                      f"sappc run or test on this machine")


def isolated_environment(domain_id: int, log_dir: Path, base: dict[str, str] | None = None) -> dict[str, str]:
    """The environment of a node process: the parent's, plus isolation and fast discovery."""
    env = dict(os.environ if base is None else base)
    # the nodes import the code this launcher runs, whatever their working directory
    code = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = os.pathsep.join([code, *[p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]])
    env.update(
        ROS_DOMAIN_ID=str(domain_id),
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        FASTRTPS_DEFAULT_PROFILES_FILE=str(fastdds_profile()),
        ROS_LOG_DIR=str(log_dir),
        PYTHONUNBUFFERED="1",
    )
    return env


def node_parameters(scenario: Scenario, kind: ControllerKind, *, realtime: bool, paths: dict[str, str], external_plant: bool = False,
                    backend: str = "native") -> dict[str, Any]:
    """The ROS parameters of every node of a run (``{"/node": {"ros__parameters": {...}}}``).

    ``external_plant``: the plant is the user's (:data:`PLANTS`), started separately: the
    recorder writes ``paths["end"]`` once the torque of the last sample is recorded, and the
    injector does not wait for a plant to subscribe to the disturbance (a plant of the user's
    own may not apply it).

    ``paths`` holds ``scenario`` (the schedule file of the injector), ``bag`` (the recorder's
    output), ``counts`` (the directory of the counts files) and ``params`` (this file, recorded
    in the bag); ``sappc run`` gives them relative to the run directory, the nodes' working
    directory, so the same run in another directory records the same bag, byte for byte.
    """
    mode = "realtime" if realtime else "lockstep"
    relayed = _relayed(scenario)
    lockstep = not realtime
    common = {"control_period_s": scenario.control_period_s, "mode": mode}

    def expected(**counts: int) -> list[str]:
        return [f"{topic.replace('__', '/')}={n}" for topic, n in counts.items()]

    def counts_file(node: str) -> str:
        return str(Path(paths["counts"]) / f"{node}.json")

    estimating = scenario.estimator is not None
    measuring = _relays_epoch(scenario)  # an estimator reads the sensors' own topics
    # issue 36: an orbit flies on the plant; momentum management is a node of its own between the
    # controller and the plant, reading the controller's rate input (one more subscriber of it)
    env = scenario.environment
    managing = scenario.momentum is not None
    sensor_relayed = any(topics[0] is STATE_ATTITUDE for topics in relayed)
    # issue 49: the mode node reads the gyro, the estimate and its figures, the reference and the tachometers (one more
    # subscriber of each, at the relay's output when one is relayed); the controller reads the gyro too (SAFE's law)
    moding = scenario.modes is not None
    gyro_relayed = any(SENSOR_GYRO in topics for topics in relayed)
    reference_relayed = any(REFERENCE_ATTITUDE in topics for topics in relayed)
    clock_subs = 5 if estimating else 4  # controller (stale watchdog), reference, injector, recorder (and the estimator: its far-ahead check)
    controller = {
        **controller_node_parameters(scenario, kind, mode=mode),  # the law, period, mode, watchdog, input bounds, flight modes' laws
        "expected_subscribers": expected(control__torque=2, controller__diagnostics=1),
        "counts_file": counts_file("controller"),
        "timing_file": str(Path(paths["counts"]).parent / "logs" / "controller_timing.json"),
        **({"duration_s": scenario.duration_s} if realtime else {}),  # nothing answered past the run's last frame
    }
    plant = {
        "inertia_kg_m2": scenario.inertia_kg_m2.ravel().tolist(),
        "q_BN0": scenario.q_BN0.tolist(),
        "omega_BN_B0_rad_s": scenario.omega_BN_B0_rad_s.tolist(),
        "duration_s": scenario.duration_s,
        "rk4_substeps": scenario.rk4_substeps,
        "max_torque_Nm": scenario.actuator.max_torque_Nm,
        # the wheel set as the scenario wrote it ('': the ideal actuator)
        "wheels": json.dumps(scenario.raw["actuator"]["wheels"]) if scenario.wheels is not None else "",
        "backend": backend,  # the plant's dynamics: native or basilisk
        # the sensor models as the scenario wrote them ('': exact measurements)
        "sensors": json.dumps(scenario.raw["sensors"]) if scenario.sensors is not None else "",
        # the sensor biases' share of the gyro's true bias (truth/gyro_bias)
        "sensor_faults": json.dumps(scenario.raw["faults"]) if scenario.sensors is not None and scenario.raw.get("faults") else "",
        "use_disturbance_topic": True,
        **_orbit_parameters(scenario),
        **common,
        # state: the controller (or the sensor relay) and the recorder; state/tf, joint_states: the recorder; /clock in lockstep only
        # (in real time the reference and the injector also take the run's first frame from the first state/attitude: FramesAhead)
        # (with an estimator, not the controller: the estimator reads the sensors' own topics, sensors/* and state/attitude_epoch)
        "expected_subscribers": expected(state__attitude=2 - measuring + 2 * realtime,
                                         state__rate=2 - measuring + (managing and not estimating and not sensor_relayed),
                                         # state/tf: the recorder, and (the bundled plant) sappc run's bring-up client once every
                                         # managed node is active: the plant's first sample waits for it (module docstring, "Bring-up")
                                         state__tf=1 + (not external_plant))
        + (["joint_states=1"] if scenario.wheels is not None else [])
        + (["truth/attitude=1", "truth/rate=1", "truth/gyro_bias=1"]
           + [f"{t.name}={1 + estimating + 2 * (moding and t is SENSOR_GYRO and not gyro_relayed)}" for t in RELAYED_SENSOR_TOPICS_FOR_ESTIMATOR]
           if scenario.sensors is not None else [])
        + ([f"/clock={clock_subs}"] if lockstep else [])
        # the magnetometer: the management node (if any) and the recorder; its truth and the tachometers
        + ([f"{STATE_MAGNETIC_FIELD.name}={1 + managing}"] if env is not None else [])
        + ([f"{TRUTH_MAGNETIC_FIELD.name}=1"] if env is not None and env.magnetometer is not None else [])
        + ([f"{STATE_WHEEL_SPEED.name}={2 + moding}"] if managing else []),
        "counts_file": counts_file("plant"),
        "timing_file": str(Path(paths["counts"]).parent / "logs" / "timing.json"),
    }
    ref = scenario.reference
    reference = {
        "q_RN0": list(ref.q_RN0),
        "amplitude_deg_s": ref.amplitude_deg_s,
        "periods_s": list(ref.periods_s),
        "duration_s": scenario.duration_s,
        **common,
        "expected_subscribers": expected(**dict.fromkeys(("reference__attitude", "reference__rate", "reference__acceleration"),
                                                         2 + (moding and not reference_relayed)), reference__tf=1),
        "counts_file": counts_file("reference"),
    }
    injector = {
        "schedule_file": paths["scenario"],
        "relay_attitude_epoch": _relays_epoch(scenario),
        "duration_s": scenario.duration_s,
        **common,
        "expected_subscribers": expected(disturbance__torque=1 if external_plant else 2)
        + [f"{faulty(t).name}={2 + (managing and not estimating and t is STATE_RATE) + 2 * (moding and t is SENSOR_GYRO) + (moding and t in RELAYED_REFERENCE_TOPICS)}"
           for topics in relayed for t in topics],
        "counts_file": counts_file("injector"),
    }
    # the estimator (a scenario with one): between the plant's measurements and the controller,
    # which reads estimate/* through a remap (_remaps); its outputs go to the controller and the recorder
    estimator = {
        **estimator_parameters_from_config(scenario.estimator),
        **common,
        "expected_subscribers": expected(estimate__attitude=2 + managing + moding, estimate__rate=2 + managing + moding)
        + [f"{t.name}={1 + (moding and t in (ESTIMATOR_COVARIANCE, ESTIMATOR_DIAGNOSTICS))}" for t in ESTIMATOR_TOPICS[2:]],
        "counts_file": counts_file("estimator"),
        "timing_file": str(Path(paths["counts"]).parent / "logs" / "estimator_timing.json"),
    } if scenario.estimator is not None else None
    # lockstep with the bundled plant: the recorder subscribes to /clock, which the plant's start
    # waits for, only once it has matched every publisher of what it records (each topic listed
    # in a node's expected_subscribers is published by that node)
    momentum = _momentum_parameters(scenario, mode, counts_file("momentum")) if managing else None
    modes = _mode_parameters(scenario, mode, counts_file("modes")) if moding else None
    published = [t for node in (controller, plant, reference, injector, *([estimator] if estimator else []), *([momentum] if momentum else []),
                                *([modes] if modes else []))
                 for t in parse_expected(cast("list[str]", node["expected_subscribers"]))]
    publishers = Counter(t for t in published if t != CLOCK.name)
    recorder = {
        "mode": mode,
        "output_dir": paths["bag"],
        # exactly the topics this run publishes (an external plant: those the bundled plant would), in the
        # contract's order: no empty channel for a fault relay, wheels, sensors or an estimator the run has not
        "topics": [t.name for t in TOPICS + FAULT_TOPICS if t.name in published],
        "metadata_files": [paths["scenario"], paths["params"]],
        "counts_file": counts_file("recorder"),
        "progress_file": str(Path(paths["counts"]).parent / PROGRESS_FILE),
        **({"end_after_s": scenario.duration_s, "end_file": paths["end"]} if external_plant else {}),
        **({"expected_publishers": [f"{t}={n}" for t, n in publishers.items()]} if lockstep and not external_plant else {}),
    }
    return {f"/{name}": {"ros__parameters": p} for name, p in
            (("controller", controller), ("plant", plant), ("reference", reference), ("injector", injector), ("recorder", recorder),
             ("estimator", estimator), ("momentum", momentum), ("modes", modes)) if p is not None}


def _orbit_parameters(scenario: Scenario) -> dict[str, Any]:
    """The plant's orbit parameters: the scenario's sections as written ('': absent), and whether a
    momentum-management node commands the rods and reads the tachometers (issue 36)."""
    raw, managing = scenario.raw, scenario.momentum is not None
    return {key: json.dumps(raw[key]) if scenario.environment is not None and raw.get(key) is not None else ""
            for key in ("orbit", "magnetorquers", "magnetometer")} | {"use_dipole_topic": managing, "publish_wheel_speed": managing}


def _momentum_parameters(scenario: Scenario, mode: str, counts_file: str) -> dict[str, Any]:
    """The momentum-management node's parameters: the law's settings, and the wheels' and rods'
    tables as the offline loop packs them (the same functions: allocation_matrix, steering_matrix),
    so that the node's kernel gets the same bits (a float's YAML text is its repr: exact)."""
    mm, w, env = scenario.momentum, scenario.wheels, scenario.environment
    assert mm is not None and w is not None and env is not None and env.magnetorquers is not None  # the scenario loader checks it
    rods = env.magnetorquers
    return {
        "mode": mode,
        "gain_per_s": float(mm.gain_per_s),
        "target_momentum_B_Nms": [float(v) for v in mm.target_momentum_B_Nms],
        "gyroscopic_feedforward": mm.gyroscopic_feedforward,
        "law": mm.law,
        "horizon_s": mm.horizon_s,
        "replan_s": mm.replan_s,
        "plan_step_s": mm.plan_step_s,
        "disturbance_time_constant_s": mm.disturbance_time_constant_s,
        # the predictive law's onboard models: the plant's orbit and field (the offline loop's, _momentum)
        "orbit_params": env.orbit.params().tolist() if mm.law == "predictive" else [],
        "field_params": env.magnetic_field.params().tolist() if mm.law == "predictive" else [],
        "wheel_axes_B": np.asarray(w.G, dtype=np.float64).ravel().tolist(),
        "wheel_spin_inertia_kg_m2": np.asarray(w.per_wheel("spin_inertia_kg_m2"), dtype=np.float64).tolist(),
        "wheel_max_torque_Nm": np.asarray(w.per_wheel("max_torque_Nm"), dtype=np.float64).tolist(),
        "wheel_allocation": allocation_matrix(w.G).ravel().tolist(),
        "rod_axes_B": np.asarray(rods.Gt, dtype=np.float64).ravel().tolist(),
        "rod_steering": np.asarray(rods.steering_matrix(), dtype=np.float64).ravel().tolist(),
        "rod_max_dipole_Am2": np.asarray(rods.max_dipoles(), dtype=np.float64).tolist(),
        # the wheels' torque and the rods' commands: the plant and the recorder
        "expected_subscribers": [f"{CONTROL_DIPOLE.name}=2", f"{CONTROL_WHEEL_TORQUE.name}=2"],
        "counts_file": counts_file,
        # flight modes (issue 49): B-dot in DETUMBLE, on each new magnetometer sample (the offline loop's stride)
        **({"flight_modes": True, "bdot_gain_N_m_s": scenario.modes.detumble_gain_N_m_s, "control_period_s": scenario.control_period_s,
            "magnetometer_stride": env.magnetometer.stride(scenario.control_period_s) if env.magnetometer is not None else 1}
           if scenario.modes is not None else {}),
    }


def _mode_parameters(scenario: Scenario, mode: str, counts_file: str) -> dict[str, Any]:
    """The mode node's parameters (issue 49): the scenario's ``modes`` section (the guards, the first
    mode, the ground's requests), the wheels' speed limits (the wheel guard) and the controller's
    input bounds (the acquisition guard reads the estimate of a sample the controller finds valid),
    as the offline loop packs them (a float's YAML text is its repr: exact)."""
    flight, wheels = scenario.modes, scenario.wheels
    assert flight is not None and wheels is not None  # the scenario loader checks it (modes need momentum management, hence wheels)
    return {
        "mode": mode,
        "control_period_s": scenario.control_period_s,
        "initial_mode": MODE_NAMES[flight.initial_mode],
        "transitions": json.dumps(asdict(flight.transitions)),
        "wheel_max_speed_rad_s": wheels.per_wheel("max_speed_rad_s").tolist(),
        # (an empty list has no type in a parameters file: none given is the default, none)
        **({"requests_at_s": [float(a) for a, _ in flight.requests], "requests_mode": [MODE_NAMES[m] for _, m in flight.requests]}
           if flight.requests else {}),
        **asdict(scenario.controller_node.input_bounds()),
        # each sample's mode: the controller, the momentum node and the recorder
        "expected_subscribers": [f"{MODE_STATUS.name}=3", f"{ESTIMATOR_HEALTH.name}=1"],  # (diagnostics: the mode in words, the recorder)
        "counts_file": counts_file,
    }


def _relays_epoch(scenario: Scenario) -> bool:
    """Whether the injector relays the tracker's epoch with the measurements: an estimator reads
    them, and the plant measures (a plant with sensor models publishes ``state/attitude_epoch``)."""
    return scenario.estimator is not None and scenario.sensors is not None


def _relayed(scenario: Scenario) -> list[tuple[Any, ...]]:
    """The paths the injector relays for the scenario's faults (each a tuple of contract topics;
    the measurements with the tracker's epoch when :func:`_relays_epoch`)."""
    faults = FaultSchedule(scenario.faults)
    sensor = RELAYED_SENSOR_TOPICS_FOR_ESTIMATOR if _relays_epoch(scenario) else RELAYED_SENSOR_TOPICS
    return [sensor if topics is RELAYED_SENSOR_TOPICS else topics for path, topics in RELAYED_PATHS.items() if faults.acts_on(path)]


def _remaps(scenario: Scenario) -> dict[str, list[str]]:
    """Each node's remaps: with an estimator the controller reads its estimate as its state, and the
    estimator is the consumer of the measurements; the consumer of each relayed path reads the
    relay's output."""
    remaps: dict[str, list[str]] = {n: [] for n in NODES}
    estimating = scenario.estimator is not None
    managing = scenario.momentum is not None
    if estimating:
        attitude, rate = controller_state_sources(estimating)
        for node in ("controller", "momentum"):  # the momentum node takes the controller's attitude and rate inputs
            remaps[node] += ["-r", f"{STATE_ATTITUDE.name}:={attitude.name}", "-r", f"{STATE_RATE.name}:={rate.name}"]
    for topics in _relayed(scenario):
        sensor = topics in (RELAYED_SENSOR_TOPICS, RELAYED_SENSOR_TOPICS_FOR_ESTIMATOR)
        actuator = topics is RELAYED_ACTUATOR_TOPICS
        consumer = ("momentum" if managing else "plant") if actuator else "estimator" if estimating and sensor else "controller"
        remaps[consumer] += relay_remaps(topics)
        if sensor and managing and not estimating:  # the controller's attitude and rate inputs, relayed
            remaps["momentum"] += relay_remaps([STATE_ATTITUDE, STATE_RATE])
    for topics in _relayed(scenario):  # flight modes: the mode node reads the gyro and the reference, the controller the gyro (SAFE)
        if scenario.modes is not None and SENSOR_GYRO in topics:
            remaps["modes"] += relay_remaps([SENSOR_GYRO])
            remaps["controller"] += relay_remaps([SENSOR_GYRO])
        if scenario.modes is not None and topics is RELAYED_REFERENCE_TOPICS:
            remaps["modes"] += relay_remaps(RELAYED_REFERENCE_TOPICS)
    if managing:  # the plant takes the management node's wheel torque as its command (the bag keeps the controller's)
        remaps["plant"] += ["-r", f"{CONTROL_TORQUE.name}:={CONTROL_WHEEL_TORQUE.name}"]
    return remaps


@dataclass
class GraphResult:
    """A finished graph run: the scenario and controller it ran, where its files are, counts and timing."""

    scenario: Scenario
    controller: ControllerKind
    run_dir: Path
    bag_dir: Path
    published: dict[str, int]
    recorded: dict[str, int]
    startup_s: float | None  # from the launch to the plant's first sample [s]: processes, imports, discovery, matching (None: an external plant)
    run_s: float
    exit_codes: dict[str, int]
    controller_timing: dict[str, Any] = field(default_factory=dict)  # the controller node's timing file
    plant_timing: dict[str, Any] = field(default_factory=dict)  # the plant node's (run_s, samples, missed)
    #: from the plant's process having built its nodes (composed: every node) to its first sample [s]: discovery and matching (None: an external plant)
    first_sample_after_up_s: float | None = None
    #: the bring-up's record (:data:`BRINGUP_FILE`): each lifecycle transition made, in order
    bringup: list[dict[str, Any]] = field(default_factory=list)
    #: ``--live``: the address the recorder's Foxglove WebSocket server listened on (None: no live view)
    live_url: str | None = None

    def mismatched_counts(self) -> dict[str, tuple[int, int]]:
        """Topics whose recorded count differs from the published one: (published, recorded)."""
        return {t: (n, self.recorded.get(t, 0)) for t, n in self.published.items() if self.recorded.get(t, 0) != n}

    @property
    def counts_match(self) -> bool:
        return not self.mismatched_counts()


#: The real-time priorities ``--rt-priority`` takes: SCHED_FIFO's range on Linux (``sched_get_priority_min/max``).
RT_PRIORITIES = range(1, 100)


def check_rt_priority(priority: int) -> None:
    """Whether this user may run processes under ``SCHED_FIFO`` at ``priority`` (tried in a child
    process, so the launcher's own scheduling is never changed).

    Raises
    ------
    ConfigError
        For a priority outside :data:`RT_PRIORITIES`, or one the system refuses (naming what it needs).
    """
    if priority not in RT_PRIORITIES:
        raise ConfigError(f"--rt-priority must be a SCHED_FIFO priority, {RT_PRIORITIES.start} to {RT_PRIORITIES.stop - 1}, got {priority}")
    probe = subprocess.run([sys.executable, "-S", "-c", f"import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param({priority}))"],
                           capture_output=True, text=True)
    if probe.returncode != 0:
        why = (probe.stderr.strip().splitlines() or ["refused"])[-1]
        raise ConfigError(f"--rt-priority {priority}: this user may not run processes under SCHED_FIFO ({why}); it needs root, "
                          f"CAP_SYS_NICE, or a real-time priority limit of at least {priority} (ulimit -r, /etc/security/limits.conf)")


class _Process:
    def __init__(self, name: str, cmd: list[str], env: dict[str, str], log_path: Path, cwd: Path, rt_priority: int | None = None) -> None:
        self.name = name
        self.log_path = log_path
        self._log = open(log_path, "wb")  # noqa: SIM115 (closed in wait)
        # under SCHED_FIFO (--rt-priority, checked by check_rt_priority first): set in the child before it
        # runs Python; every thread it starts (the middleware's, the recorder's writer) inherits it
        preexec = (lambda: os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(rt_priority))) if rt_priority is not None else None
        self.proc = subprocess.Popen(cmd, env=env, cwd=cwd, stdout=self._log, stderr=subprocess.STDOUT, start_new_session=True,
                                     preexec_fn=preexec)  # noqa: PLW1509 (a system call, no lock or allocation of Python's)

    def stop(self, timeout_s: float = STOP_TIMEOUT_S, progress: Callable[[], object] | None = None) -> tuple[int, bool]:
        """SIGINT, wait, SIGKILL once it has not exited within ``timeout_s``, counted from the
        last change of ``progress()`` when given (a node that is still working, such as a recorder
        closing a long bag, is not killed); returns (exit code, killed)."""
        killed = False
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            seen = progress() if progress is not None else None
            deadline = time.monotonic() + timeout_s
            while self.proc.poll() is None:
                try:
                    self.proc.wait(max(0.0, min(STOP_CHECK_S, deadline - time.monotonic())))
                except subprocess.TimeoutExpired:
                    now = progress() if progress is not None else None
                    if now != seen:
                        seen, deadline = now, time.monotonic() + timeout_s
                    elif time.monotonic() >= deadline:
                        os.killpg(self.proc.pid, signal.SIGKILL)
                        self.proc.wait()
                        killed = True
        self._log.close()
        return self.proc.returncode, killed

    def tail(self, lines: int = 15) -> str:
        return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])


@contextlib.contextmanager
def _interrupts_deferred(what: str) -> Iterator[None]:
    """Hold SIGINT while ``what`` runs (node start-up or shutdown must not be cut in half), then
    raise the :class:`KeyboardInterrupt` it would have raised, once, with the line it printed as
    its argument (the command's entry, :mod:`sappc.__main__`, then prints no other)."""
    caught: list[int] = []

    def hold(signum: int, _frame: object) -> None:
        if not caught:
            print(f"sappc run: interrupted while {what}; finishing that first", file=sys.stderr, flush=True)
        caught.append(signum)

    old = {sig: signal.signal(sig, hold) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
    if caught:
        raise KeyboardInterrupt(f"interrupted while {what}")


def _terminate_as_interrupt(_signum: int, _frame: object) -> None:
    """SIGTERM (``kill``, a CI runner's stop) stops a run as Ctrl-C does: every node stopped cleanly."""
    raise KeyboardInterrupt


def _bytes_under(directory: Path) -> int:
    """The size of every file under ``directory`` [bytes]: it grows while a recorder writes its bag
    (what it took, the sort's runs, the sorted file)."""
    total = 0
    for path in directory.rglob("*"):
        with contextlib.suppress(OSError):  # a sort's temporary file removed meanwhile
            total += path.stat().st_size if path.is_file() else 0
    return total


class _ProgressLine:
    """``sappc run``'s progress line, every :data:`PROGRESS_PERIOD_S` while the run goes on: the
    run's time as recorded (the newest state's, from the recorder's progress file), the samples
    recorded and their rate since the previous line; before the first sample, how long the nodes
    have been starting."""

    def __init__(self, path: Path, duration_s: float, start: float, say: Callable[[str], None]) -> None:
        self.path, self.duration_s, self.start, self.say = path, duration_s, start, say
        self.last_print = start
        self.last_samples: tuple[float, int] | None = None  # (when, samples) of the previous line
        self.done = False  # the last sample's line is printed: nothing more
        self.done_at: float | None = None  # when the last sample was seen in
        self.advanced_at = start  # when the samples recorded last grew (or the start)

    def update(self) -> None:
        now = time.monotonic()
        if self.done or now - self.last_print < PROGRESS_PERIOD_S:
            return
        self.last_print = now
        try:
            progress = json.loads(self.path.read_text())
        except (OSError, ValueError):  # not written yet (no sample), or being replaced
            self.say(f"sappc run: starting the nodes, no sample yet ({now - self.start:.0f} s)")
            return
        samples, t_s = int(progress["state_samples"]), float(progress["t_s"])
        rate = "" if self.last_samples is None else f", {(samples - self.last_samples[1]) / (now - self.last_samples[0]):.0f} samples/s"
        if self.last_samples is None or samples > self.last_samples[1]:
            self.advanced_at = now
        self.last_samples = (now, samples)
        share = f" ({100 * t_s / self.duration_s:.0f} %)" if self.duration_s > 0 else ""
        self.done = self.duration_s > 0 and t_s >= self.duration_s
        if self.done:
            self.done_at = now
        self.say(f"sappc run: t = {t_s:.1f} s of {self.duration_s:g} s{share}, {samples} samples recorded{rate}"
                 + ("; the last sample is in" if self.done else ""))


def _stop_nodes(procs: Mapping[str, _Process], stop_order: Sequence[str], bag_dir: Path, ticker: Ticker,
                on_closed: Callable[[], bool] | None = None) -> tuple[dict[str, int], bool]:
    """Stop the started nodes of ``stop_order`` in that order (publishers first, they wait for
    acknowledgements; the recorder last, it drains its queues), each still running a step of
    ``ticker`` ("stopping the nodes: NAME"; the recorder's, or the composed process's, with the
    size of its bag so far, which is also the stop's sign of progress: :meth:`_Process.stop`);
    return each one's exit code and whether one had to be killed.  ``on_closed`` (``--live``) is
    called at each check of the recorder's stop: it writes the run's verdict once the recorder waits
    for it (:class:`_LiveVerdict`), which counts as progress."""
    exit_codes: dict[str, int] = {}
    killed_any = False
    for name in stop_order:
        if name not in procs:
            continue
        if procs[name].proc.poll() is None:
            ticker.step("stopping the nodes", name)
        recording = name in ("recorder", "composed")

        def bag_written() -> tuple[int, bool]:
            written = _bytes_under(bag_dir)
            ticker.detail(f"{name}, its bag {written / 1e6:.1f} MB so far")  # noqa: B023 (called within this iteration)
            return written, on_closed() if on_closed is not None else False

        exit_codes[name], killed = procs[name].stop(progress=bag_written if recording else None)
        killed_any |= killed
    ticker.idle()
    return exit_codes, killed_any


def _check_live_port(host: str, port: int) -> None:
    """``--live``: a port taken or a host that is not this machine's stops the run before anything starts.

    Raises
    ------
    ConfigError
        Naming the address and the system's reason.
    """
    import socket

    if not 0 <= port <= 65535:
        raise ConfigError(f"--live: the port must be 0 to 65535, got {port}")
    if port == 0:
        return
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
        with socket.socket(infos[0][0], socket.SOCK_STREAM) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server does: a port in TIME_WAIT is free
            s.bind(infos[0][4])
    except OSError as exc:
        raise ConfigError(f"--live: cannot listen on {host}:{port} ({exc.strerror or exc})") from None


class _LiveAddress:
    """``--live``: the address the recorder writes (:data:`LIVE_FILE`), printed once it is there."""

    def __init__(self, path: Path, host: str) -> None:
        self.path, self.host = path, host
        self.url: str | None = None

    def poll(self) -> None:
        if self.url is not None:
            return
        try:
            self.url = str(json.loads(self.path.read_text())["url"])
        except (OSError, ValueError, KeyError):
            return
        where = "this machine only" if self.host in ("127.0.0.1", "localhost", "::1") else "unauthenticated: anyone who reaches the port reads every topic"
        print(f"sappc run: live view at {self.url} (Foxglove: Open connection, Foxglove WebSocket; {where})", file=sys.stderr, flush=True)


class _LiveVerdict:
    """``--live``: once the recorder has closed its bag and waits (:data:`LIVE_WAITING_FILE`), the
    run's verdict to :data:`LIVE_VERDICT_FILE`: ``verdict(scenario, run_dir)`` (checked at each pass
    of the run's loop: the composed process closes its bag before it ends by itself; or in the
    stop of five processes), or :meth:`fail` for a run that did not end
    normally (interrupted, failed)."""

    def __init__(self, run_dir: Path, scenario: Scenario, verdict: Callable[[Scenario, Path], tuple[bool, str]] | None) -> None:
        self.run_dir, self.scenario, self.verdict = run_dir, scenario, verdict
        self.written = False
        if verdict is None:  # nothing to compute: written now
            self._write(False, "the run's verdict is printed by sappc run")

    def fail(self, text: str) -> None:
        """The run did not end normally: ``text`` is the verdict, now (unless one is written)."""
        if not self.written:
            self._write(True, text)

    def _write(self, failed: bool, text: str) -> None:
        with contextlib.suppress(OSError):  # the run directory gone: the recorder stops waiting at its limit
            write_json_whole(self.run_dir / LIVE_VERDICT_FILE, {"failed": failed, "text": text})
        self.written = True

    def __call__(self) -> bool:
        """Whether the verdict is written (computing it when due)."""
        if not self.written and self.verdict is not None and (self.run_dir / LIVE_WAITING_FILE).exists():
            try:
                failed, text = self.verdict(self.scenario, self.run_dir)
            except Exception as exc:  # noqa: BLE001 (sappc run computes it again and reports the error itself)
                failed, text = True, f"the verdict could not be computed ({type(exc).__name__}: {exc})"
            self._write(failed, text)
        return self.written


def _fastdds_shm_clean() -> None:
    tool = Path(sys.executable).parent / "fastdds"
    if tool.exists():
        subprocess.run([str(tool), "shm", "clean"], capture_output=True, check=False)


#: Serialises the process-wide environment the bring-up client's ROS context is created in.
_ENV_LOCK = threading.Lock()


@contextlib.contextmanager
def _environment(values: Mapping[str, str]) -> Iterator[None]:
    """``os.environ`` updated with ``values`` while the context lasts (the middleware reads the
    discovery range and the Fast DDS profile from the environment when a participant is made),
    then restored."""
    with _ENV_LOCK:
        old = {key: os.environ.get(key) for key in values}
        os.environ.update(values)
        try:
            yield
        finally:
            for key, value in old.items():
                if value is None:
                    os.environ.pop(key, None)
                else:
                    os.environ[key] = value


class BringUpFailed(RuntimeError):
    """A lifecycle transition of the bring-up failed: ``node`` and ``transition`` name it."""

    def __init__(self, node: str, transition: str, state: str) -> None:
        super().__init__(f"node {node}: its {transition} transition failed (it stays {state})")
        self.node, self.transition = node, transition


class _BringUp:
    """``sappc run``'s lifecycle client (module docstring, "Bring-up"): a plain rclpy node in the
    launcher's process, on the run's domain and environment, that configures each managed node of
    ``nodes`` (:data:`MANAGED_NODES` order), then activates each, through the standard
    ``/<node>/change_state`` services (``lifecycle_msgs/srv/ChangeState``), one transition at a
    time; then, with ``gate``, subscribes to ``state/tf``, which the bundled plant waits for
    before its first sample (``expected_subscribers``), and lets go of everything once the
    plant's first sample has come.

    :meth:`poll` does what is due without blocking longer than ``timeout_s`` (the run's loop calls
    it in place of its sleep, so the loop's checks go on: a node that exits, the deadline, the stall
    rule, the progress line); a failed transition raises :class:`BringUpFailed`.
    """

    def __init__(self, nodes: Sequence[str], domain: int, env: Mapping[str, str], gate: bool) -> None:
        import rclpy
        from lifecycle_msgs.srv import ChangeState
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions
        from rclpy.utilities import try_shutdown

        self.nodes = list(nodes)
        self.steps = [(name, t) for t in BRINGUP_TRANSITIONS for name in self.nodes]
        self.record: list[dict[str, Any]] = []
        self.active_at: float | None = None  # when the last transition was answered (CLOCK_MONOTONIC [s])
        self.gate_open_at: float | None = None  # when the plant's first sample came through the gate
        self._gate = gate
        self._gate_sub: Any = None
        self._pending: tuple[str, str, Any, float] | None = None
        isolation = {k: env[k] for k in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "FASTRTPS_DEFAULT_PROFILES_FILE", "ROS_LOG_DIR") if k in env}
        with _environment(isolation):  # the participant is made with the node: both inside
            self.context = Context()
            rclpy.init(context=self.context, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
            try:
                self.node = rclpy.create_node("sappc_run_bringup", context=self.context, start_parameter_services=False)
                self.executor = SingleThreadedExecutor(context=self.context)
                self.executor.add_node(self.node)
                self.clients = {name: self.node.create_client(ChangeState, f"/{name}/change_state") for name in self.nodes}
            except BaseException:
                try_shutdown(context=self.context)
                raise
        self._request = ChangeState.Request
        self._closed = False

    @property
    def up(self) -> bool:
        """Every managed node of the run is active."""
        return self.active_at is not None

    @property
    def done(self) -> bool:
        """Every node active and, with a gate, the plant's first sample through it: the client is let go."""
        return self._closed

    def poll(self, timeout_s: float) -> None:
        """Spin the client's node for at most ``timeout_s`` and take the bring-up's next step.

        Raises
        ------
        BringUpFailed
            When a node answers a transition with ``success: false``.
        """
        if self._closed:
            time.sleep(timeout_s)
            return
        self.executor.spin_once(timeout_sec=timeout_s)
        if self._pending is not None:
            name, transition, future, asked = self._pending
            if not future.done():
                return
            self._pending = None
            answer = future.result()
            now = time.monotonic()
            self.record.append({"node": name, "transition": transition, "requested_monotonic_s": asked, "answered_monotonic_s": now,
                                "success": bool(answer is not None and answer.success)})
            if answer is None or not answer.success:
                raise BringUpFailed(name, transition, "unconfigured" if transition == "configure" else "inactive")
            self.steps.pop(0)
        if self.steps:
            from lifecycle_msgs.msg import Transition

            name, transition = self.steps[0]
            client = self.clients[name]
            if client.service_is_ready():
                ids = {"configure": Transition.TRANSITION_CONFIGURE, "activate": Transition.TRANSITION_ACTIVATE}
                future = client.call_async(self._request(transition=Transition(id=ids[transition])))
                self._pending = (name, transition, future, time.monotonic())
            return
        if self.active_at is None:
            self.active_at = time.monotonic()
            if not self._gate:
                self.close()
                return
            from sappc_msgs_py.contract import STATE_TF, qos_profile

            self._gate_sub = self.node.create_subscription(STATE_TF.msg_class, STATE_TF.name, self._on_gate, qos_profile(), raw=True)
        elif self.gate_open_at is not None:
            self.close()

    def _on_gate(self, _raw: bytes) -> None:
        if self.gate_open_at is None:
            self.gate_open_at = time.monotonic()

    def write(self, path: Path) -> None:
        """The bring-up's record (:data:`BRINGUP_FILE`), as JSON (not written when the directory is gone)."""
        with contextlib.suppress(OSError):
            path.write_text(json.dumps({"nodes": self.nodes, "transitions": self.record, "active_monotonic_s": self.active_at,
                                        "gate_open_monotonic_s": self.gate_open_at}, indent=1))

    def close(self) -> None:
        """Let go of the client: its subscription, node and context (twice is once)."""
        if self._closed:
            return
        self._closed = True
        from rclpy.utilities import try_shutdown

        # cleanup on every path (an interrupted spin included): a step that fails must not keep the
        # nodes from being stopped after it
        for step in (lambda: self.executor.shutdown(timeout_sec=1.0), self.node.destroy_node, lambda: try_shutdown(context=self.context)):
            with contextlib.suppress(Exception):
                step()


def _bring_up(bringup: _BringUp, procs: Mapping[str, _Process], compose: bool, start: float, say: Callable[[str], None]) -> None:
    """One step of the bring-up (:meth:`_BringUp.poll`, at most 50 ms); its end said once; a failed
    transition stops the run with one line naming the node and the transition, and that node's
    (or the composed process's) last log lines."""
    was_up = bringup.up
    try:
        bringup.poll(0.05)
    except BringUpFailed as exc:
        log = procs["composed" if compose else exc.node]
        raise RuntimeError(f"{exc}; last log lines:\n{log.tail()}") from None
    if bringup.active_at is not None and not was_up:
        say(f"sappc run: {', '.join(bringup.nodes)} configured and active through their lifecycle services "
            f"({bringup.active_at - start:.1f} s after the launch)")


def run_graph(
    scenario_path: str | Path,
    *,
    out_dir: str | Path | None = None,
    controller: str | None = None,
    realtime: bool = False,
    domain_id: int | None = None,
    timeout_s: float | None = None,
    progress: bool = True,
    compose: bool = False,
    plant: str = "native",
    rt_priority: int | None = None,
    live_port: int | None = None,
    live_host: str = "127.0.0.1",
    verdict: Callable[[Scenario, Path], tuple[bool, str]] | None = None,
    live_wait_subscribers: int = 0,
) -> GraphResult:
    """Run ``scenario_path`` through the node graph; see the module docstring.

    ``compose``: every node in one process on one executor (:mod:`sappc.graph.container`)
    instead of one process per node; the same parameters, topics, bag and metrics.
    ``rt_priority``: real time only: the node processes run under ``SCHED_FIFO`` at this priority
    (:data:`RT_PRIORITIES`; root or ``CAP_SYS_NICE``), so that other work on the host cannot delay
    their frames (docs/how-to/realtime.md has what it changes, measured).
    ``live_port``: ``--live``: the recorder also serves every recorded topic to Foxglove on a
    Foxglove WebSocket at ``live_host``:``live_port`` (0: any free port; :mod:`sappc.graph.recorder`,
    "Live view"), with the run's progress; the address is printed (and is
    :attr:`GraphResult.live_url`).  ``verdict(scenario, run_dir)``: called once the bag is closed
    in a run that ended normally, while the recorder still serves: ``(failed, text)``, shown in
    the view.  ``live_wait_subscribers``: the run starts once every recorded topic has that many
    live-view subscriptions (lockstep on the bundled plant).  None of them changes the bag or params.yaml (the live parameters are on the recorder's
    command line).
    ``plant``: one of :data:`PLANTS` (``"basilisk"``: the plant node on Basilisk's dynamics, the
    ``[basilisk]`` extra); with ``"external"`` no time limit applies unless
    ``timeout_s`` is given (the user's plant may start whenever it is ready).
    ``domain_id``: the ROS domain of the run; ``None``: ``ROS_DOMAIN_ID`` when the environment
    sets it (the ROS convention), else the first free id of :func:`domain_ids`
    (:func:`requested_domain_id`); either way it is claimed with a lock file, so two ``sappc``
    runs never share it.

    Raises
    ------
    ConfigError
        For an invalid scenario, or an ``out_dir`` that already holds a run.
    RuntimeError
        When a node fails (its log tail is in the message) or the run exceeds ``timeout_s``; without
        ``timeout_s``, a real-time run that exceeds 60 s plus twice its duration, or a lockstep run
        that records no new sample for :data:`LOCKSTEP_STALL_S` or whose nodes do not stop within
        :data:`CLOSE_BASE_S` plus :data:`CLOSE_S_PER_SAMPLE` a sample of its last sample (lockstep
        has no wall-clock pace: a loaded machine may fly it slower than real time).
    """
    if threading.current_thread() is threading.main_thread():
        old_term = signal.signal(signal.SIGTERM, _terminate_as_interrupt)
        # SIGINT stops a run even when the run was started with SIGINT ignored (a command started
        # in the background by a non-interactive shell: Python then installs no handler of its own)
        old_int = signal.signal(signal.SIGINT, signal.default_int_handler)
        try:
            return _run_graph(scenario_path, out_dir=out_dir, controller=controller, realtime=realtime, domain_id=domain_id,
                              timeout_s=timeout_s, progress=progress, compose=compose, plant=plant, rt_priority=rt_priority,
                              live_port=live_port, live_host=live_host, verdict=verdict,
                              live_wait_subscribers=live_wait_subscribers)
        finally:
            signal.signal(signal.SIGTERM, old_term)
            signal.signal(signal.SIGINT, old_int)
    return _run_graph(scenario_path, out_dir=out_dir, controller=controller, realtime=realtime, domain_id=domain_id,
                      timeout_s=timeout_s, progress=progress, compose=compose, plant=plant, rt_priority=rt_priority,
                      live_port=live_port, live_host=live_host, verdict=verdict,
                              live_wait_subscribers=live_wait_subscribers)


def _run_graph(scenario_path: str | Path, *, out_dir: str | Path | None, controller: str | None, realtime: bool,
               domain_id: int | None, timeout_s: float | None, progress: bool, compose: bool, plant: str,
               rt_priority: int | None, live_port: int | None = None, live_host: str = "127.0.0.1",
               verdict: Callable[[Scenario, Path], tuple[bool, str]] | None = None,
               live_wait_subscribers: int = 0) -> GraphResult:
    if plant not in PLANTS:
        raise ConfigError(f"plant must be one of {list(PLANTS)}, got {plant!r}")
    if rt_priority is not None:
        if not realtime:
            raise ConfigError("--rt-priority is for real time (--realtime): a lockstep run waits for each message, not for the clock")
        check_rt_priority(rt_priority)
    if live_port is not None:
        _check_live_port(live_host, live_port)
    if live_wait_subscribers and (live_port is None or realtime or plant == "external"):
        raise ConfigError("--wait-subscribers is for --live in lockstep on the bundled plant (the recorder holds the run's start)")
    if live_wait_subscribers < 0:
        raise ConfigError(f"--wait-subscribers must be >= 0, got {live_wait_subscribers}")
    preferred_domain, domain_source = requested_domain_id(domain_id)
    # claimed first: a domain in use stops the run before anything is written or started
    with claim_domain_id(preferred_domain, source=domain_source) as domain:
        external = plant == "external"
        scenario_path = bundled_scenario_path(scenario_path)  # a file, or a bundled scenario's name
        scenario = load_scenario(scenario_path)
        if scenario.environment is not None and (realtime or plant != "native"):  # issue 36: lockstep on the bundled plant only
            raise ConfigError(f"{scenario_path}: an orbit (sections orbit, magnetorquers, magnetometer, momentum_management) runs on the "
                              f"graph in lockstep on the native plant only, got {'--realtime' if realtime else f'--plant {plant}'}: "
                              "run it in lockstep, or offline with sappc simulate (docs/how-to/momentum.md)")
        if scenario.modes is not None and scenario.estimator is None:  # issue 49: the mode node reads the estimator's health
            raise ConfigError(f"{scenario_path}: flight modes (section modes) run on the graph with an estimator only (the mode node "
                              "reads its estimate, covariance and health); run it offline with sappc simulate (docs/design/modes.md)")
        if scenario.estimator is not None and scenario.sensors is None:  # the estimator node reads what sensor models publish
            raise ConfigError(f"{scenario_path}: the estimator reads the sensors' own topics (sensors/gyro, sensors/star_tracker, "
                              "state/attitude_epoch), which the plant publishes with sensor models: add a sensors section "
                              "(star_tracker, gyro), or run it offline with sappc simulate")
        kind = scenario.resolve_controller(controller)
        scenario.controller_config(kind)  # validate before any process starts
        # the controller's first step, as the node will compute it: a start the core refuses (the
        # 180 deg singularity) stops here with the core's error, before any process starts
        ref0 = scenario.reference.sample([0.0])
        if scenario.modes is None:  # (with flight modes the law starts at TRACK's entry, clamped: docs/design/modes.md)
            scenario.build_controller(kind).step(0.0, scenario.control_period_s, scenario.q_BN0, scenario.omega_BN_B0_rad_s,
                                                 ref0.q_RN[0], ref0.omega_RN_R[0], ref0.omegadot_RN_R[0])
        stamp = time.strftime("%Y%m%d-%H%M%S")
        run_dir = Path(out_dir) if out_dir is not None else default_output_dir("run", f"{scenario.name}-{kind.value}-{stamp}")
        if run_dir.exists() and any(run_dir.iterdir()):
            raise ConfigError(f"--out {run_dir} exists and is not empty; choose a new directory")
        for sub in ("logs", "counts"):
            (run_dir / sub).mkdir(parents=True, exist_ok=True)
        scenario_copy = run_dir / "scenario.yaml"
        text = Path(scenario_path).read_text()
        # the file as written (its comments kept), or, for one that extends another, the whole
        # scenario it resolves to: the injector reads it, the bag records it, both without the base
        scenario_copy.write_text(yaml.safe_dump(scenario.raw, sort_keys=False) if EXTENDS_KEY in (safe_load_yaml(text, source=str(scenario_path)) or {}) else text)
        params_path = run_dir / "params.yaml"
        bag_dir = run_dir / "bag"
        # relative to the run directory, the nodes' working directory (node_parameters)
        paths = {"scenario": scenario_copy.name, "bag": bag_dir.name, "counts": "counts", "params": params_path.name, "end": END_FILE}
        params = node_parameters(scenario, kind, realtime=realtime, paths=paths, external_plant=external,
                                 backend="basilisk" if plant == "basilisk" else "native")
        params_path.write_text(yaml.safe_dump(params, sort_keys=False))
        remaps = _remaps(scenario)
        # the wall-clock limit: timeout_s; else real time 60 s + twice the duration; lockstep none, but the stall rule
        # (LOCKSTEP_STALL_S, then the close's budget) below; an external plant none
        stall_rule = timeout_s is None and not realtime and not external
        limit = timeout_s if timeout_s is not None else (60.0 + 2.0 * scenario.duration_s if realtime and not external else float("inf"))
        nodes = [n for n in NODES if not (external and n == "plant") and not (n == "estimator" and scenario.estimator is None)
                 and not (n == "momentum" and scenario.momentum is None) and not (n == "modes" and scenario.modes is None)]

        def say(msg: str) -> None:
            if progress:
                print(msg, file=sys.stderr, flush=True)

        env = isolated_environment(domain, (run_dir / "logs").resolve())
        procs: dict[str, _Process] = {}
        # from the last sample on, the stop's lines (issue 46: a line at least every 2 s to the end)
        ticker = Ticker(lambda msg: say(f"sappc run: {msg}"), period_s=PROGRESS_PERIOD_S)
        start = time.monotonic()
        # the managed nodes start unconfigured (managed:=true): the launcher's client brings them up (_BringUp)
        managed = [n for n in MANAGED_NODES if n in nodes]
        node_args = {name: ["--ros-args", "-r", f"__node:={name}", "--params-file", params_path.name, *remaps[name],
                            *(["-p", "managed:=true"] if name in managed else [])] for name in nodes}
        if live_port is not None:  # on the command line, not in params.yaml, which the bag records
            node_args["recorder"] += ["-p", f"live_port:={live_port}", "-p", f"live_host:={live_host}", "-p", f"live_file:={LIVE_FILE}",
                                      "-p", f"live_verdict_file:={LIVE_VERDICT_FILE}",
                                      "-p", f"live_wait_subscribers:={live_wait_subscribers}"]
        live = _LiveAddress(run_dir / LIVE_FILE, live_host) if live_port is not None else None
        # the verdict once the recorder waits for it: in the stop (five processes), or before the composed process ends by itself
        live_verdict = _LiveVerdict(run_dir, scenario, verdict) if live is not None else None
        completed = False
        if compose:  # one process: it ends by itself when the plant finishes, the nodes stopping in STOP_ORDER
            composition = run_dir / "composition.json"
            composition.write_text(json.dumps([{"name": name, "args": node_args[name]} for name in nodes], indent=1))
            # relative to the run directory, the process's working directory, as every other path it is given
            commands = {"composed": [sys.executable, "-m", "sappc.graph.container", composition.name]}
            lead, stop_order = "composed", ["composed"]
        else:
            commands = {name: [sys.executable, "-m", NODE_CLASSES[name][0], *node_args[name]] for name in nodes}
            lead, stop_order = "plant", [n for n in STOP_ORDER if n in nodes]
        end_file = run_dir / END_FILE
        bringup: _BringUp | None = None

        def ended() -> bool:
            """The plant finished (it exits), or the recorder saw an external plant's last sample."""
            return end_file.exists() if external else procs[lead].proc.poll() is not None

        try:
            for name, cmd in commands.items():
                with _interrupts_deferred("starting the nodes"):  # a started process is always in procs, to be stopped
                    procs[name] = _Process(name, cmd, env, run_dir / "logs" / f"{name}.log", cwd=run_dir, rt_priority=rt_priority)
            with _interrupts_deferred("starting the nodes"):  # while the processes start: the lifecycle client, on the run's domain
                bringup = _BringUp(managed, domain, env, gate=not external)
            say(f"sappc run: {scenario.name} with {kind.value} ({'real time' if realtime else 'lockstep'}"
                f"{', composed' if compose else ''}), domain {domain} ({domain_source}), in {run_dir}")
            while external and not bringup.up:  # your plant is told to start once the managed nodes are active
                for name, p in procs.items():
                    if p.proc.poll() is not None:
                        raise RuntimeError(f"node {name} exited early with status {p.proc.returncode}; last log lines:\n{p.tail()}")
                if time.monotonic() > start + limit:
                    raise RuntimeError(f"the run did not finish within {limit:.0f} s (see {run_dir / 'logs'})")
                if live is not None:
                    live.poll()
                _bring_up(bringup, procs, compose, start, say)
            if external:
                say(f"sappc run: waiting for your plant on ROS_DOMAIN_ID={domain} (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST): it publishes "
                    f"{'/clock, ' if not realtime else ''}state/attitude and state/rate and applies control/torque; the run ends once the "
                    f"torque of t = {scenario.duration_s:g} s is recorded, or on Ctrl-C")
            deadline = start + limit
            line = _ProgressLine(run_dir / PROGRESS_FILE, scenario.duration_s, start, say)
            stopping = False
            while not ended():
                for name, p in procs.items():
                    if p.proc.poll() is not None and (external or name != lead):
                        raise RuntimeError(f"node {name} exited early with status {p.proc.returncode}; last log lines:\n{p.tail()}")
                now = time.monotonic()
                if now > deadline:
                    raise RuntimeError(f"the run did not finish within {limit:.0f} s (see {run_dir / 'logs'})")
                if stall_rule and line.done_at is None and now - line.advanced_at > LOCKSTEP_STALL_S:
                    raise RuntimeError(f"no new sample recorded for {LOCKSTEP_STALL_S:.0f} s: the lockstep run is stalled (see {run_dir / 'logs'})")
                if stall_rule and line.done_at is not None and line.last_samples is not None \
                        and now - line.done_at > CLOSE_BASE_S + CLOSE_S_PER_SAMPLE * line.last_samples[1]:
                    raise RuntimeError(f"the nodes did not stop within {CLOSE_BASE_S + CLOSE_S_PER_SAMPLE * line.last_samples[1]:.0f} s "
                                       f"of the last sample (see {run_dir / 'logs'})")
                line.update()
                if live is not None and live_verdict is not None:
                    live.poll()
                    live_verdict()  # once the recorder waits for it (its .wait file: the bag closed), not on the progress
                    # line's "last sample is in", which reads the recorder's 0.5 s progress file and may never see the end
                if not bringup.done:
                    _bring_up(bringup, procs, compose, start, say)
                if line.done and not stopping:  # the lead ends by itself: the plant its run, the composed process its nodes
                    ticker.step("stopping the nodes", f"waiting for the {'plant' if lead == 'plant' else 'composed nodes'} to end")
                    stopping = True
                ticker.poll()
                if bringup.done:
                    time.sleep(0.05)
            run_end = time.monotonic()
            completed = True
            if not external and procs[lead].proc.returncode != 0:
                raise RuntimeError(f"the {lead} process failed with status {procs[lead].proc.returncode}; last log lines:\n{procs[lead].tail()}")
        finally:
            # publishers first (they wait for acknowledgements), the recorder last (it drains); a
            # further Ctrl-C cannot cut this short and leave a node running
            with _interrupts_deferred("stopping the nodes cleanly"), ticker:  # its thread: a process's exit may take seconds
                if bringup is not None:  # the lifecycle client let go (whatever happened), its record kept
                    bringup.close()
                    bringup.write(run_dir / BRINGUP_FILE)
                if live is not None and live_verdict is not None:
                    live.poll()
                    if not (completed and (external or procs[lead].proc.returncode == 0)):
                        live_verdict.fail("the run did not end normally (interrupted or failed): no verdict")
                exit_codes, killed_any = _stop_nodes(procs, stop_order, bag_dir, ticker, live_verdict)
                if killed_any:
                    _fastdds_shm_clean()
        failed = {n: c for n, c in exit_codes.items() if c != 0}
        if failed:
            name = next(iter(failed))
            raise RuntimeError(f"node {name} exited with status {failed[name]}; last log lines:\n{procs[name].tail()}")

    if bag_dir.is_dir():  # beside the bag, once the recorder has closed it: Foxglove's layout for it (not in the MCAP file)
        from sappc.bag.live import write_layout

        write_layout(bag_dir)
    counts = {p.stem: json.loads(p.read_text()) for p in (run_dir / "counts").glob("*.json")}
    recorded = counts.pop("recorder", {})
    published: dict[str, int] = {}
    for c in counts.values():
        for topic, n in c.items():
            published[topic] = published.get(topic, 0) + n
    timing_path = run_dir / "logs" / "timing.json"
    timing = json.loads(timing_path.read_text()) if timing_path.exists() else {}
    total = run_end - start
    run_s = float(timing.get("run_s", total))  # the plant's first sample to its last
    first_sample = timing.get("first_sample_monotonic_s")  # CLOCK_MONOTONIC is one clock for every process
    startup_s = float(first_sample) - start if first_sample is not None else (None if external else total - run_s)
    up = timing.get("nodes_up_monotonic_s")
    after_up_s = float(first_sample) - float(up) if first_sample is not None and up is not None else None
    return GraphResult(
        scenario=scenario,
        controller=kind,
        run_dir=run_dir,
        bag_dir=bag_dir,
        published=published,
        recorded=recorded,
        startup_s=startup_s,
        first_sample_after_up_s=after_up_s,
        run_s=run_s,
        exit_codes=exit_codes,
        bringup=json.loads((run_dir / BRINGUP_FILE).read_text())["transitions"],
        controller_timing=json.loads(ctrl_timing.read_text()) if (ctrl_timing := run_dir / "logs" / "controller_timing.json").exists() else {},
        plant_timing=timing,
        live_url=live.url if live is not None else None,
    )
