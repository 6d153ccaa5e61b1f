"""Odometry over a recorded TUM-layout sequence, frame by frame as from a live camera.

    python examples/recorded_sequence.py [SEQ_DIR]

Defaults to the dynamic TUM sequence of the shared data (two people walking; the data root
is ``$JAXVO_DATA``, else ``../shared/data`` beside the checkout). Writes the trajectory and
one overlay image per 10 frames.
"""

import sys
from pathlib import Path

import cv2

import jaxvo
from jaxvo.host.readers.io import data_root
from jaxvo.host.services.compile_cache import setup_compile_cache
from jaxvo.host.writers.masks import overlay_panel

default = data_root() / "tum_fr3_walking_halfsphere_50"
root = Path(sys.argv[1]) if len(sys.argv) > 1 else default
setup_compile_cache()  # later runs load the compiled step (~20 s saved)
try:
    seq = jaxvo.open_sequence(root)  # intrinsics from its camera.txt (or camera="tum_fr3")
except jaxvo.InputError as exc:  # one line, no traceback: say what to pass
    sys.exit(f"recorded_sequence.py: {exc}; pass a TUM-layout folder, or set JAXVO_DATA to the "
             "folder holding tum_fr3_walking_halfsphere_50")
odo = jaxvo.Odometry(seq.intrinsics, seed=0)
out = Path("recorded_out")
out.mkdir(exist_ok=True)
prev = None
for frame in seq:
    r = odo.process(frame.bgr, frame.depth, frame.timestamp)
    if r.output is not None and frame.index % 10 == 0:
        # the labels of a step sit on the previous image of its frame pair
        panel = overlay_panel(prev.bgr, r.output, odo.cfg.cell)  # thesis Fig. 5.1 style
        cv2.imwrite(str(out / f"{prev.index:06d}.jpg"), panel)
    if r.status != jaxvo.Status.OK:
        print(f"frame {frame.index}: skipped ({r.status.reason})")
    prev = frame
jaxvo.write_trajectory(out / "traj.txt", odo.trajectory)
print(f"{len(seq)} frames; trajectory and overlays in {out}/")
