"""hydropump_ros: the ROS 2 face of hydropump (thin nodes over the pure packages)."""
