"""Synthetic Atacama-style world and rosbag2 bag writer."""
