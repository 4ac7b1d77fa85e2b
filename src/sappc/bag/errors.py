"""The errors of :mod:`sappc.bag`, in a module of their own: the recorder node
(:mod:`sappc.graph.recorder`, through :mod:`sappc.bag.rosbag2`) raises them without importing the
bag readers and the metrics they feed (numba, scipy: 130 MB of the recorder's memory)."""

from __future__ import annotations

from gnc_common.validation import ConfigError

__all__ = ["BagError"]


class BagError(ConfigError):
    """The path is not a readable bag, or lacks what is asked of it."""
