"""The controllers a scenario can run (:class:`ControllerKind`).

A module of its own, with nothing but the standard library: the command line lists these names
as its ``--controller`` choices (:mod:`sappc.cli`) before any command has imported the scenario's
models (:mod:`sappc.scenario`, about 60 ms, which re-exports the class), so that ``sappc report``
forks its figure worker that much sooner.
"""

from __future__ import annotations

from enum import Enum

__all__ = ["ControllerKind"]


class ControllerKind(str, Enum):
    """The controllers a scenario can run."""

    SAPPC = "sappc"
    TRAPPC = "trappc"
    BLFPPC = "blfppc"
    MRP_FEEDBACK = "mrp_feedback"
