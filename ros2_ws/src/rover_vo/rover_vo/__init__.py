"""Stereo + IMU visual odometry library and node."""
