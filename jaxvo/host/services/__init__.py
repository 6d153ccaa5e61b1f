"""The services the commands share: the compile cache, the memory a run needs, the
progress line, and the peers (OpenCV's and Open3D's odometry) run on the same frames."""
