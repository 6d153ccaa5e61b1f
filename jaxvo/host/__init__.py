"""Host code (numpy, OpenCV, files, threads), in four rooms: ``frontend`` (a frame's camera,
depth and grid flow, the keyframes' tracks), ``readers`` (folders, bags, recordings,
downloads), ``writers`` (every output of a run) and ``services`` (compile cache, memory,
progress, the peers)."""
