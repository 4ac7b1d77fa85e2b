"""The interface contract between plants and controllers.

* :mod:`.contract`: topic names, message types, frame ids, QoS (the table in its docstring
  and in docs/reference/topics.md is what a plant must speak);
* :mod:`.convert`: numpy <-> message conversions (quaternions stay ``(x, y, z, w)``);
* :mod:`.schemas`: ``ros2msg`` schema texts and RIHS01 type hashes for MCAP recording.

The numerical cores do not depend on this package.
"""
