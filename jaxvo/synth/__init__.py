"""Synthetic dynamic RGB-D scenes with exact ground truth: ``scenes`` (the entry points:
built-in sequences, composites into real frames, files), ``scenario`` (what a scene is made
of: boxes, camera motion, sensor effects, the presets), ``sequence`` (a scene rendered frame
by frame, host) and ``render`` (its JAX ray caster)."""
