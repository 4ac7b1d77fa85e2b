"""Offline runs, without ROS: the compiled whole-run loop of controller and plant kernels
(``compiled_loop``) and ``sappc simulate`` (``simulate``: a scenario in, metrics and histories out)."""
