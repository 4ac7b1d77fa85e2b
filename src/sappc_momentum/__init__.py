"""Momentum management (issue 36): flight software that keeps the reaction wheels away from
saturation with magnetorquers.  ``core``: the compiled law (:mod:`sappc_momentum.core.law`).
Never imports the simulator."""
