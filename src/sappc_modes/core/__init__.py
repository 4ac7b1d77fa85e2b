"""The flight-mode kernel and its configuration (no ROS, no clock)."""
