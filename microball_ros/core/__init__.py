"""Core numerics, simulation and tracking: numpy/scipy/OpenCV only, never rclpy."""
