"""ROS 1 and ROS 2 bags: the reader and the frame sources of camera drivers' bags and of RealSense and Orbbec
SDK recordings."""
