"""The momentum-management kernels and their configuration (no ROS, no clock)."""
