"""Offline runs, without ROS: the closed loop of controller and plant cores (``closed_loop``) and
``sappc simulate`` (``simulate``: a scenario in, metrics and histories out)."""
