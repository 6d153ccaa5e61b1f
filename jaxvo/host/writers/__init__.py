"""The writers: every output a run makes, whole or not at all (files and folders, masks and
overlays, ROS 2 bags, Rerun recordings, the static map)."""
