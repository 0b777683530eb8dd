"""hydropump_ctrl: control and identification for the hydropump plant (no ROS)."""
