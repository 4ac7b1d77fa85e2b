"""The ROS 2 graph tools: ``sappc run`` (``launch``: start, isolate and stop the nodes), the MCAP
recorder node (``python -m sappc.graph.recorder``) and ``sappc replay`` (``replay``).

Only this subpackage of ``sappc`` imports ``rclpy`` (``tests/test_layering.py``); this
``__init__`` imports nothing, so that a node started with ``python -m`` pays for its own module only.
"""
