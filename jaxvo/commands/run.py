"""``jaxvo run SEQ_DIR --out traj.txt``: odometry over a recorded TUM-layout sequence.

Frames are processed one at a time by the streaming odometry (pipelined: a frame's device
step runs while the next frame is read and its flow computed) and every pose is written to
the trajectory file as soon as it is known, so an interrupted run keeps what it computed.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    from jaxvo.camera import PRESETS

    p.add_argument("sequence", metavar="SEQ_DIR", help="folder in the TUM RGB-D layout")
    p.add_argument("--out", "-o", required=True, metavar="FILE",
                   help="trajectory to write (TUM format, camera-to-world; evo reads it)")
    p.add_argument("--camera", metavar="PRESET",
                   help="intrinsics preset when the folder has no camera.txt "
                   "(" + ", ".join(sorted(PRESETS)) + ")")
    p.add_argument("--max-diff", type=float, default=0.02, metavar="S",
                   help="largest rgb/depth timestamp difference when associating (default 0.02 s)")
    p.add_argument("--frames", type=int, metavar="N", help="process only the first N frames")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed of hypothesis sampling")
    p.add_argument("--cell", type=int, default=16, help="grid cell size in pixels (default 16)")
    p.add_argument("--hypotheses", type=int, default=20, help="hypotheses per frame, H")
    p.add_argument("--masks", metavar="DIR",
                   help="write per-frame label masks (PNG, pixel value = identifier, 1 = static)")
    p.add_argument("--dynamic-masks", metavar="DIR",
                   help="write per-frame dynamic-pixel masks (PNG, 255 = dynamic, 0 = static) "
                   "for other odometry to ignore; the last frame takes the last pair's labels")
    p.add_argument("--overlays", metavar="DIR",
                   help="write per-frame overlay images of the labels (thesis Fig. 5.1 style)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress line")


def _peak_rss_mib() -> float:
    """This process's peak resident memory, MiB: Linux's VmHWM (the high-water mark of this
    program's own address space), else ``ru_maxrss``, which on Linux also keeps the peak of
    the process before ``exec`` (a large parent's pages shared through ``fork``)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return round(int(line.split()[1]) / 1024, 1)
    except OSError:
        pass
    import resource

    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)


def run(args: argparse.Namespace) -> int:
    import time
    from collections import Counter

    import cv2
    import numpy as np

    from jaxvo.config import Config
    from jaxvo.errors import InputError
    from jaxvo.io import TrajectoryWriter, check_depth_scale, first_pose, open_sequence
    from jaxvo.masks import dynamic_pixels, grid_to_pixels, overlay_panel
    from jaxvo.odometry import Odometry
    from jaxvo.plugin import mask_png
    from jaxvo.progress import Progress
    from jaxvo.status import Status

    seq = open_sequence(args.sequence, camera=args.camera, max_diff=args.max_diff)
    n = len(seq) if args.frames is None else min(len(seq), max(args.frames, 0))
    if n < 2:
        raise InputError(f"{args.sequence}: {n} frame(s); odometry needs at least 2")
    cfg = Config(cell=args.cell, num_hypotheses=args.hypotheses)
    for folder in (args.masks, args.overlays, args.dynamic_masks):
        if folder:
            Path(folder).mkdir(parents=True, exist_ok=True)

    first = seq[0]
    check_depth_scale(first.depth, seq.intrinsics, where=f"{args.sequence} frame 0")
    gt = seq.groundtruth
    odo = Odometry(seq.intrinsics, cfg=cfg, seed=args.seed, T_w_c0=first_pose(seq))
    progress = Progress("jaxvo run", n - 1, enabled=not args.quiet)
    skipped: Counter[str] = Counter()
    times: list[float] = []
    written = 0
    recent: dict[int, object] = {}  # the last few submitted frames, by streaming index
    last_dyn = None
    interrupted = False

    def record(r) -> None:
        """Write one finished frame: its pose, and its pair's masks and overlay."""
        nonlocal written, last_dyn
        writer.write(r.timestamp, r.T_w_c)
        written += 1
        if r.status != Status.OK:
            skipped[r.status.reason] += 1
        prev_frame = recent.get(r.index - 1)  # the pair's labels sit on its previous image
        if r.output is None or prev_frame is None:
            return
        h, w = prev_frame.depth.shape
        if args.masks:
            ids = grid_to_pixels(r.ids, h, w, cfg.cell).astype(np.uint8)
            cv2.imwrite(str(Path(args.masks) / f"{prev_frame.index:06d}.png"), ids)
        if args.dynamic_masks:  # jaxvo.plugin: step k labels image k
            last_dyn = mask_png(dynamic_pixels(r.output.moving, h, w, cfg.cell))
            cv2.imwrite(str(Path(args.dynamic_masks) / f"{prev_frame.index:06d}.png"), last_dyn)
        if args.overlays:
            panel = overlay_panel(prev_frame.bgr, r.output, cfg.cell)
            cv2.imwrite(str(Path(args.overlays) / f"{prev_frame.index:06d}.jpg"), panel)

    with TrajectoryWriter(args.out, comment=f"jaxvo run {args.sequence}") as writer:
        try:
            submitted = 0
            for i in range(n):
                t0 = time.perf_counter()
                try:
                    frame = first if i == 0 else seq[i]
                except InputError as exc:  # unreadable frame: skip it, keep going
                    skipped[f"unreadable frame ({exc})"] += 1
                    continue
                recent[submitted] = frame
                recent.pop(submitted - 3, None)
                submitted += 1
                # pipelined: this frame's device step runs while the next one is read and
                # its flow computed; the result that comes back is the previous frame's
                r = odo.submit(frame.bgr, frame.depth, frame.timestamp)
                if r is not None:
                    record(r)
                times.append(time.perf_counter() - t0)  # reading and writing included
                if i:
                    progress(i)
        except KeyboardInterrupt:
            interrupted = True
        r = odo.flush()  # the last frame's result (also after an interruption)
        if r is not None:
            record(r)
    last_frame = recent.get(submitted - 1) if submitted else None
    if args.dynamic_masks and last_dyn is not None and last_frame is not None:
        # the last frame has no pair of its own: it takes the last available label map
        cv2.imwrite(str(Path(args.dynamic_masks) / f"{last_frame.index:06d}.png"), last_dyn)
    progress.close()

    steady = times[2:] if len(times) > 3 else times[1:]
    fps = len(steady) / sum(steady) if steady and sum(steady) > 0 else 0.0
    summary = {
        "sequence": str(args.sequence),
        "frames": n,
        "camera": getattr(seq, "camera_source", "given"),
        "poses_written": written,
        "trajectory": str(args.out),
        "frames_per_second": round(fps, 2),
        "first_frame_pair_seconds": round(times[1], 3) if len(times) > 1 else None,
        "skipped": dict(skipped),
        "interrupted": interrupted,
        "peak_rss_mib": _peak_rss_mib(),
    }
    if gt is not None and written >= 3:
        from jaxvo.io import read_trajectory
        from jaxvo.metrics import ate, rpe

        est = read_trajectory(args.out)
        try:
            a = ate(gt, est, max_diff=args.max_diff)
            r1 = rpe(gt, est, delta=1, delta_unit="frames", max_diff=args.max_diff)
        except InputError as exc:  # e.g. every pose carried: nothing to align
            summary["scores_not_computed"] = str(exc)
        else:
            summary["ate_rmse_m"] = round(a.stats.rmse, 5)
            summary["rpe_trans_rmse_m_per_frame"] = round(r1.trans.rmse, 5)
            summary["rpe_rot_rmse_deg_per_frame"] = round(r1.rot.rmse, 4)

    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        print(f"jaxvo run: {written} poses -> {args.out}" + (" (interrupted)" if interrupted else ""))
        print(f"  speed      {fps:.1f} frames/s steady state, reading and writing included "
              f"(first pair {summary['first_frame_pair_seconds']} s, compile included)")
        total_skip = sum(skipped.values())
        print(f"  camera     {summary['camera']}")
        print(f"  skipped    {total_skip} of {n - 1} frame pairs")
        print(f"  memory     {summary['peak_rss_mib']:.0f} MiB peak resident")
        for reason, count in skipped.most_common():
            print(f"    {count:5d}  {reason}")
        if "scores_not_computed" in summary:
            print(f"  ATE / RPE  not computed: {summary['scores_not_computed']}")
        if "ate_rmse_m" in summary:
            print(f"  ATE        {summary['ate_rmse_m']:.4f} m rmse (aligned, ground truth in folder)")
            print(f"  RPE        {summary['rpe_trans_rmse_m_per_frame']:.4f} m, "
                  f"{summary['rpe_rot_rmse_deg_per_frame']:.3f} deg rmse per frame")
    if interrupted:
        print("jaxvo: interrupted; the poses computed so far are in the trajectory file",
              file=sys.stderr)
        return 130
    return 0 if written >= 2 and sum(skipped.values()) < n - 1 else 1
