"""Intel RealSense depth cameras through librealsense's Python binding (pyrealsense2, the `realsense` extra)."""
