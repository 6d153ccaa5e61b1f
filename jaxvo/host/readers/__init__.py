"""The readers: sequences as they come (TUM-layout folders, ROS 1 and ROS 2 bags, RealSense
recordings) and the benchmark downloads."""
