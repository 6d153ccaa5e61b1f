"""``jaxvo map SEQ_DIR --traj traj.txt --dynamic-masks DIR --out map.ply``: the static map.

Every frame of the trajectory has its depth fused into one voxel-filtered point cloud with
the pixels of its dynamic mask left out (:mod:`jaxvo.host.mapping`); beside it the same map
with nothing left out, where the movers leave smeared ghosts, and a picture of both from
above and from the first camera. ``jaxvo run --map map.ply`` does the same in one go.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

EPILOG = """\
examples:
  jaxvo run SEQ_DIR --out traj.txt --dynamic-masks dyn/
  jaxvo map SEQ_DIR --traj traj.txt --dynamic-masks dyn/ --out map.ply
  jaxvo run SEQ_DIR --out traj.txt --map map.ply          # the same in one go

output: --out map.ply the static map, map_all.ply beside it the map with nothing left out
  (binary PLY, x y z float metres in the trajectory's world frame, red green blue; Open3D,
  MeshLab and CloudCompare read it), and map.png the two seen from the first camera and
  from above (up is the first camera's up). With --rerun-save the maps also go into a Rerun
  recording (pip install 'jaxvo[viz]').

the static map: a reading in a dynamic mask (nonzero pixels of DIR/<rgb timestamp>.png, as
  jaxvo run --dynamic-masks writes them), grown by --grow pixels, is left out, and so is
  every reading in a cube of --vote-voxel metres where more than --vote-share of the
  readings were in a mask. A frame of the trajectory without a mask file is left out of
  the static map (the summary counts them). Every pose of --traj must have a frame of
  SEQ_DIR within --max-diff seconds.
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from jaxvo.cli.main import EXIT_STATUSES
    from jaxvo.host.mapping import GROW, VOTE_SHARE, VOTE_VOXEL

    p.epilog = EPILOG + "\n" + EXIT_STATUSES
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("sequence", metavar="SEQ_DIR",
                   help="the sequence the trajectory was run on (TUM layout or a ROS bag)")
    p.add_argument("--traj", required=True, metavar="FILE",
                   help="its trajectory (TUM format, camera-to-world; jaxvo run --out)")
    p.add_argument("--dynamic-masks", metavar="DIR",
                   help="its dynamic masks (jaxvo run --dynamic-masks); without: only the map "
                   "with nothing left out")
    p.add_argument("--out", "-o", required=True, metavar="FILE.ply",
                   help="the static map (FILE_all.ply and FILE.png are written beside it)")
    add_map_options(p, GROW, VOTE_VOXEL, VOTE_SHARE)
    p.add_argument("--camera", metavar="PRESET", help="intrinsics preset, as jaxvo run's")
    p.add_argument("--max-diff", type=float, default=0.02, metavar="S",
                   help="largest timestamp difference between a pose and its frame, seconds "
                   "(default 0.02)")
    p.add_argument("--rerun-save", metavar="FILE.rrd",
                   help="also write the maps into a Rerun recording (pip install 'jaxvo[viz]')")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")


def add_map_options(p: argparse.ArgumentParser, grow: int, vote_voxel: float,
                    vote_share: float) -> None:
    """The fusion's options, shared with ``jaxvo run --map``."""
    p.add_argument("--voxel", type=float, default=0.02, metavar="M",
                   help="the map's voxel side, metres (default 0.02)")
    p.add_argument("--max-depth", type=float, default=4.0, metavar="M",
                   help="depth readings farther than this are left out, metres (default 4)")
    p.add_argument("--grow", type=int, default=grow, metavar="PX",
                   help=f"pixels around a dynamic pixel also left out (default {grow})")
    p.add_argument("--vote-voxel", type=float, default=vote_voxel, metavar="M",
                   help=f"side of the cubes voted on, metres (default {vote_voxel})")
    p.add_argument("--vote-share", type=float, default=vote_share, metavar="F",
                   help="a cube with more than this share of its readings in the dynamic "
                   f"masks is left out whole (default {vote_share}; 1: no vote)")


def check_map_options(args: argparse.Namespace) -> None:
    """The fusion's options checked (InputError naming the option)."""
    import math

    from jaxvo.errors import InputError

    for option, value in (("--voxel", args.voxel), ("--max-depth", args.max_depth),
                          ("--vote-voxel", args.vote_voxel)):
        if not (math.isfinite(value) and value > 0):
            raise InputError(f"{option} must be a positive number of metres, got {value}")
    if args.grow < 0:
        raise InputError(f"--grow must be 0 or more pixels, got {args.grow}")
    if not (math.isfinite(args.vote_share) and 0 <= args.vote_share <= 1):
        raise InputError(f"--vote-share must be from 0 to 1, got {args.vote_share}")


def map_outputs(path: str | Path) -> dict[str, Path]:
    """The files a map writes: ``{option: path}`` for the static map (``path``), the map
    with nothing left out (``<stem>_all.ply``) and the picture (``<stem>.png``)."""
    p = Path(path)
    return {"map": p, "map (nothing left out)": p.with_name(p.stem + "_all.ply"),
            "map picture": p.with_suffix(".png")}


def make_maps(seq, traj, dynamic, args, outputs: dict[str, Path], *, where: str,
              frames: int | None = None, logger=None, on_static=None) -> dict:
    """Fuse, write the maps and their picture (and into ``logger``, and the static map to
    ``on_static``: ``jaxvo run --out-bag``); the summary's part."""
    from jaxvo.host.io import write_image
    from jaxvo.host.mapping import fuse_maps, map_picture, matched_poses, write_ply

    poses = matched_poses(seq, traj, where=where, max_diff=args.max_diff, frames=frames)
    maps = fuse_maps(seq, poses, dynamic, voxel=args.voxel, max_depth=args.max_depth,
                     grow=args.grow, vote_voxel=args.vote_voxel, vote_share=args.vote_share)
    write_ply(outputs["map"], maps.static)
    if on_static is not None:
        on_static(maps.static)
    summary = {"map": str(outputs["map"]), "map_points": len(maps.static.points),
               "frames_fused": maps.frames, "frames_without_mask": maps.no_mask}
    if dynamic is not None:
        full = outputs["map (nothing left out)"]
        write_ply(full, maps.full)
        summary.update(map_all=str(full), map_all_points=len(maps.full.points))
    picture = outputs["map picture"]
    write_image(picture, map_picture(maps, seq.intrinsics, poses[0][1], seq.height, seq.width))
    summary["map_picture"] = str(picture)
    if logger is not None:
        logger.log_map("static", maps.static)
        if dynamic is not None:
            logger.log_map("full", maps.full)
    return summary


def run(args: argparse.Namespace) -> int:
    from jaxvo.errors import InputError
    from jaxvo.host.io import check_outputs, open_sequence, output_file, read_trajectory
    from jaxvo.host.mapping import mask_reader

    check_map_options(args)
    seq = open_sequence(args.sequence, camera=args.camera, max_diff=args.max_diff)
    outputs = map_outputs(args.out)
    if args.dynamic_masks is None:
        del outputs["map (nothing left out)"]
    files = {("--out" if k == "map" else f"--out's {k}"): v for k, v in outputs.items()}
    if args.rerun_save:
        files["--rerun-save"] = Path(args.rerun_save)
    reads = seq.files() + [Path(args.traj)]
    if args.dynamic_masks:
        masks = Path(args.dynamic_masks)
        if not masks.is_dir():
            raise InputError(f"--dynamic-masks {masks}: not a folder")
        reads += sorted(masks.glob("*.png"))
    check_outputs(reads, files=files)
    for what, path in files.items():
        output_file(path, what=what)
    logger = None
    if args.rerun_save:
        from jaxvo.host.recording import RerunLogger, import_rerun

        import_rerun("--rerun-save")
        logger = RerunLogger(save=args.rerun_save)
    traj = read_trajectory(args.traj)
    dynamic = mask_reader(args.dynamic_masks) if args.dynamic_masks else None
    try:
        summary = make_maps(seq, traj, dynamic, args, outputs, where=f"--traj {args.traj}",
                            logger=logger)
    finally:
        if logger is not None:
            logger.close()
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        print(f"jaxvo map: {summary['map_points']} points -> {summary['map']} (dynamic pixels "
              f"left out), from {summary['frames_fused']} frames")
        if "map_all" in summary:
            print(f"  beside it  {summary['map_all_points']} points -> {summary['map_all']} "
                  "(nothing left out)")
        if summary["frames_without_mask"]:
            print(f"  left out   {summary['frames_without_mask']} frames without a dynamic "
                  "mask (from the static map)")
        print(f"  picture    {summary['map_picture']}")
    return 0
