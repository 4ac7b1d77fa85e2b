"""The ground layer: what the controller, the simulator and the topic contract all need.

- :mod:`gnc_common.attitude`: quaternion and attitude maths (one convention: scalar last,
  Hamilton product, ``q_BN`` maps body to inertial components).
- :mod:`gnc_common.collector`: the garbage collector during a start-up or a compile.
- :mod:`gnc_common.validation`: input and configuration checks, and the two error types
  every layer raises (:class:`~gnc_common.validation.ConfigError`,
  :class:`~gnc_common.validation.InputError`).

It imports none of ``sappc_controller``, ``spacecraft_sim``, ``sappc_msgs_py`` or ``sappc``
(``tests/test_layering.py`` enforces it): flight software may depend on it, it depends on nothing
of theirs.
"""
