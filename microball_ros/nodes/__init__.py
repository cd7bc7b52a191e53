"""rclpy nodes: thin wrappers msg -> arrays -> core -> msg, one console script each."""
