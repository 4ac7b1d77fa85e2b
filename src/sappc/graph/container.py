"""The composed graph (``sappc run --compose``): the nodes of a run in one process, on one executor.

ROS 2's composition practice in Python: the same node classes, parameters, remappings and topics
as the five processes of ``sappc run``, built in one process and spun by one rclpy
``EventsExecutor`` (:func:`sappc_msgs_py.runtime.run_nodes`).  The messages still go through
the middleware (rclpy has no intra-process transport), so the bag and the metrics are those of
the five processes; what is saved is the process start-ups, the discovery between processes and
the context switches of every message.

    python -m sappc.graph.container COMPOSITION.json

``COMPOSITION.json`` (written by :func:`sappc.graph.launch.run_graph`) lists the nodes in the
order they start, each ``{"name": ..., "args": [ROS arguments]}`` with the same ``--ros-args``
(``__node:=`` remap, ``--params-file``, topic remaps) its own process would get.  The run ends when
the plant finishes (or on SIGINT / SIGTERM); the nodes then stop in :data:`STOP_ORDER`.

The managed nodes (the controller, estimator, mode and momentum nodes: their arguments carry
``-p managed:=true``) are built unconfigured, as in their own processes, and ``sappc run``'s
lifecycle client brings them up through their standard services, which this process's executor
answers between the other nodes' callbacks (:mod:`sappc.graph.launch`, "Bring-up"); the plant
built here waits for that client as it does in its own process.
"""

from __future__ import annotations

import importlib
import json
import sys
from pathlib import Path
from typing import Any

from gnc_common.validation import ConfigError
from sappc_msgs_py.runtime import ProjectNode, run_nodes

__all__ = ["NODE_CLASSES", "STOP_ORDER", "build_nodes", "main"]

#: The class of each node of a run: (module, class); ``python -m <module>`` runs the node in its
#: own process (what ``sappc run`` does without ``--compose``).
NODE_CLASSES: dict[str, tuple[str, str]] = {
    "recorder": ("sappc.graph.recorder", "RecorderNode"),
    "estimator": ("sappc_estimator.node", "EstimatorNode"),
    "controller": ("sappc_controller.node", "ControllerNode"),
    "momentum": ("sappc_momentum.node", "MomentumNode"),
    "modes": ("sappc_modes.node", "ModeNode"),
    "reference": ("spacecraft_sim.reference", "ReferenceNode"),
    "injector": ("spacecraft_sim.disturbance", "InjectorNode"),
    "plant": ("spacecraft_sim.plant_node", "PlantNode"),
}
#: Stop order: publishers first (each waits for its subscribers' acknowledgements), the recorder
#: last (it drains its queues); the same order in which ``sappc run`` signals the five processes.
STOP_ORDER = ("plant", "estimator", "modes", "controller", "momentum", "reference", "injector", "recorder")


def build_nodes(composition: list[dict[str, Any]]) -> list[ProjectNode]:
    """The nodes of ``composition``, built in its order, returned in :data:`STOP_ORDER`.

    Raises
    ------
    ConfigError
        For a node name that is not in :data:`NODE_CLASSES`, or one listed twice.
    """
    names = [str(entry.get("name")) for entry in composition]
    unknown = [n for n in names if n not in NODE_CLASSES]
    if unknown or len(set(names)) != len(names):
        raise ConfigError(f"composition: nodes must be distinct names among {list(NODE_CLASSES)}, got {names}")
    built: dict[str, ProjectNode] = {}
    for entry in composition:
        module, cls = NODE_CLASSES[entry["name"]]
        node_class = getattr(importlib.import_module(module), cls)
        built[entry["name"]] = node_class(node_name=entry["name"], cli_args=list(entry["args"]))
    return [built[n] for n in STOP_ORDER if n in built]


def main(argv: list[str] | None = None) -> int:
    """Run the composition file given as the one argument."""
    args = list(sys.argv[1:] if argv is None else argv)
    if args in (["-h"], ["--help"]):
        print(__doc__)
        return 0
    if len(args) != 1:
        print("usage: python -m sappc.graph.container COMPOSITION.json", file=sys.stderr)
        return 2
    composition = json.loads(Path(args[0]).read_text())
    return run_nodes(lambda _args: build_nodes(composition), argv=[sys.argv[0]])


if __name__ == "__main__":
    sys.exit(main())
