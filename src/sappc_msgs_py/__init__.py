"""The interface contract between plants and controllers (topic names, message types, QoS,
frames, numpy <-> message conversions, MCAP schemas).

It is filled in with the ROS 2 node graph; the numerical cores do not depend on it.
"""
