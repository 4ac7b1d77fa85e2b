"""The composed graph's container (``python -m sappc.graph.container``): its input checks.  The
composed run itself is tested end to end in ``tests/tools/graph/test_graph.py`` (the same bag as
the five processes, byte for byte)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from gnc_common.validation import ConfigError
from sappc.graph.container import NODE_CLASSES, STOP_ORDER, build_nodes
from sappc.graph.launch import NODES

from conftest import ROOT


@pytest.mark.parametrize("names", [["plant", "pilot"], ["plant", "plant"]], ids=["unknown", "twice"])
def test_a_composition_names_distinct_known_nodes(names: list[str]) -> None:
    with pytest.raises(ConfigError, match="composition: nodes must be distinct names among"):
        build_nodes([{"name": n, "args": []} for n in names])


def test_every_node_of_a_run_has_a_class_and_a_place_in_the_stop_order() -> None:
    assert set(NODE_CLASSES) == set(NODES) == set(STOP_ORDER)
    assert STOP_ORDER[0] == "plant" and STOP_ORDER[-1] == "recorder"  # publishers first, the recorder last


def test_the_container_explains_itself_and_refuses_a_wrong_call() -> None:
    ok = subprocess.run([sys.executable, "-m", "sappc.graph.container", "--help"], capture_output=True, text=True, cwd=ROOT)
    assert ok.returncode == 0 and "COMPOSITION.json" in ok.stdout
    bad = subprocess.run([sys.executable, "-m", "sappc.graph.container"], capture_output=True, text=True, cwd=ROOT)
    assert bad.returncode == 2 and "usage: python -m sappc.graph.container COMPOSITION.json" in bad.stderr
