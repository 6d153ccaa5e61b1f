"""ORB-SLAM3 with jaxvo's dynamic masks, frame by frame, as on a robot.

    pip install pyorbslam3    # ORB-SLAM3's bindings, GPL-3.0; the wheel wants the apt
                              # libraries libgl1 libegl1 libopengl0 libsm6 libice6 libx11-6 libxext6
    python examples/orbslam3_with_jaxvo_masks.py [SEQ_DIR]

jaxvo runs in this process and ORB-SLAM3 in a child process (``bench/orbslam3_peer.py``),
fed over a pipe, so the two work side by side and jaxvo never loads the GPL code. Each step
of jaxvo labels the previous image of its frame pair, so every frame reaches ORB-SLAM3 one
frame late (33 ms at 30 Hz), with its dynamic pixels taken out (``mask_frame``: their depth
set to 0, as ``jaxvo run --dynamic-masks`` writes them, the way that served ORB-SLAM3 best
on the TUM walking clip: docs/report/orbslam3_clip_masking.md), so ORB-SLAM3 makes no map
points on the people. The
vocabulary is ``$PYORBSLAM3_VOCAB``, else the one
beside the shared data (``bench/orbslam3_peer.py`` says more).

Defaults to the TUM walking clip of the shared data (two people walking). Writes jaxvo's
and ORB-SLAM3's trajectories (TUM format) and, where the sequence has ground truth, prints
their ATE.
"""

import sys
from pathlib import Path

import jaxvo
from jaxvo.host.readers.io import data_root, first_pose
from jaxvo.host.writers.masks import dynamic_pixels

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))
from orbslam3_peer import OrbSlam3, anchored, mask_frame, missing


def main() -> int:
    default = data_root() / "tum_fr3_walking_halfsphere_50"
    root = Path(sys.argv[1]) if len(sys.argv) > 1 else default
    if why := missing():
        print(f"ORB-SLAM3 cannot run here: {why}")
        return 1
    seq = jaxvo.open_sequence(root)
    odo = jaxvo.Odometry(seq.intrinsics, seed=0, T_w_c0=first_pose(seq))
    orb = OrbSlam3(seq.intrinsics, seq.width, seq.height)  # starts its own process
    prev, dynamic = None, None
    for frame in seq:  # a camera's frames, one at a time
        r = odo.process(frame.bgr, frame.depth, frame.timestamp)
        if r.output is not None:  # this step's labels lie on the previous image
            dynamic = dynamic_pixels(r.output.dynamic, seq.height, seq.width, odo.cfg.cell)
        if prev is not None:
            orb.track(*mask_frame(prev.bgr, prev.depth, dynamic), prev.timestamp)
        prev = frame
    orb.track(*mask_frame(prev.bgr, prev.depth, dynamic), prev.timestamp)  # the last mask
    run = orb.finish()  # ORB-SLAM3's end-of-run trajectory, after its final optimisation

    out = Path("orbslam3_out")
    out.mkdir(exist_ok=True)
    traj = anchored(run.trajectory, seq.groundtruth)  # starts where the truth starts
    jaxvo.write_trajectory(out / "jaxvo.txt", odo.trajectory)
    jaxvo.write_trajectory(out / "orbslam3_x_jaxvo.txt", traj)
    print(f"{len(seq)} frames, {len(traj)} tracked by ORB-SLAM3 ({run.ms_per_frame:.0f} ms a "
          f"frame); trajectories in {out}/")
    if seq.groundtruth is not None:
        for name, t in (("jaxvo", odo.trajectory), ("ORB-SLAM3 x jaxvo", traj)):
            ate = jaxvo.trajectory_scores(seq.groundtruth, t)["ate_rmse_m"]
            print(f"ATE {name}: {1e3 * ate:.1f} mm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
