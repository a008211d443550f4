"""The real cell: a UR arm through ur-rtde and a RealSense through pyrealsense2, as one cell."""
