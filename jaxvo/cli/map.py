"""``jaxvo map SEQ_DIR --traj traj.txt --dynamic-masks DIR --out map.ply``: the static map.

Every frame of the trajectory has its depth fused into one voxel-filtered point cloud with
the pixels of its dynamic mask left out (:mod:`jaxvo.host.writers.mapping`); beside it the same map
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
  SEQ_DIR within --max-diff seconds, a frame of its own.

camera and depth: as jaxvo run read them. A trajectory jaxvo run wrote names in its first
  lines the sequence, its camera and its depth scale: the map reads the depth the same way
  (jaxvo run --depth-scale 1000, then jaxvo map: at 1000), and a trajectory of another
  sequence is refused. --camera, --intrinsics and --depth-scale override that, as they
  override the folder's camera.txt (with a warning where they differ). Where the
  trajectory's motion fits the depth worse than no motion, a warning says so.
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from jaxvo.cli.main import EXIT_STATUSES

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
    add_map_options(p)
    camera = p.add_mutually_exclusive_group()
    camera.add_argument("--camera", metavar="PRESET",
                        help="intrinsics preset, as jaxvo run's (default: the camera the run "
                        "read, named in --traj's first lines, else the folder's)")
    camera.add_argument("--intrinsics", metavar="FX,FY,CX,CY",
                        help="the camera's intrinsics in pixels, as jaxvo run's")
    p.add_argument("--depth-scale", type=float, metavar="UNITS",
                   help="raw depth units per metre of the 16-bit depth images, as jaxvo run's "
                   "(default: the run's, named in --traj's first lines, else the camera's)")
    p.add_argument("--max-diff", type=float, default=0.02, metavar="S",
                   help="largest timestamp difference between a pose and its frame, seconds "
                   "(default 0.02)")
    p.add_argument("--rerun-save", metavar="FILE.rrd",
                   help="also write the maps into a Rerun recording (pip install 'jaxvo[viz]')")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")


# the fusion's options: field of MapOptions, flag, metavar, help (its default added)
_FUSION = (
    ("voxel", "--voxel", "M", "the map's voxel side, metres"),
    ("max_depth", "--max-depth", "M", "depth readings farther than this are left out, metres"),
    ("grow", "--grow", "PX", "pixels around a dynamic pixel also left out"),
    ("vote_voxel", "--vote-voxel", "M", "side of the cubes voted on, metres"),
    ("vote_share", "--vote-share", "F",
     "a cube with more than this share of its readings in the dynamic masks is left out whole"),
)

# what map_options' checks call each field
_NAMES = {field: flag for field, flag, _, _ in _FUSION}


def add_map_options(p: argparse.ArgumentParser) -> None:
    """The fusion's options, whose defaults are :class:`~jaxvo.host.writers.mapping.MapOptions`'
    (which ``jaxvo run --map`` takes). An option not given stays None, so that the parser
    needs no NumPy (the help reads the defaults when printed) and :func:`prepare` knows
    which were given."""
    from jaxvo.cli.later import Later

    for field, flag, metavar, text in _FUSION:
        note = "; 1: no vote" if field == "vote_share" else ""
        action = p.add_argument(flag, type=int if field == "grow" else float, metavar=metavar,
                                help=f"{text} (default %(default_value)s{note})")
        action.default_value = Later("jaxvo.host.writers.mapping", "MapOptions",
                                     lambda options, f=field: f"{getattr(options(), f):g}")


def map_options(args: argparse.Namespace):
    """The :class:`~jaxvo.host.writers.mapping.MapOptions` the command line gives."""
    from jaxvo.host.writers.mapping import MapOptions

    return MapOptions(**_fusion_given(args), max_diff=args.max_diff)


def _fusion_given(args: argparse.Namespace) -> dict:
    """The fusion's options the command line gives, by field."""
    return {f: getattr(args, f) for f in _NAMES if getattr(args, f) is not None}


def prepare(args: argparse.Namespace) -> tuple:
    """The options checked, then the inputs being there, then --out: ``(camera,)`` for
    :func:`run`. The options' checks need NumPy, loaded only where one is given; a
    trajectory, a sequence or a masks' folder that is not there, and an --out that is a
    folder, lies in a folder that is not there or is standard output, are answered before
    NumPy loads, and so before the trajectory and the sequence are read (with one of those
    wrong too, the --out is said first). What the outputs must not overwrite is checked
    in :func:`run`, once the sequence is open."""
    from jaxvo.cli.inputs import require_sequence, require_trajectory
    from jaxvo.errors import InputError
    from jaxvo.host.writers.outputs import file_target

    if _fusion_given(args):
        map_options(args).check(names=_NAMES)
    camera = _camera(args)
    require_trajectory(args.traj)
    require_sequence(args.sequence)
    if args.dynamic_masks and not Path(args.dynamic_masks).is_dir():
        raise InputError(f"--dynamic-masks {Path(args.dynamic_masks)}: not a folder")
    file_target(args.out, what="--out")
    return (camera,)


def _camera(args: argparse.Namespace):
    """--intrinsics (parsed) or --camera, and --depth-scale checked; the camera module
    (NumPy) loaded only where --intrinsics or --depth-scale is given."""
    camera = args.camera
    if args.intrinsics:
        from jaxvo.host.frontend.camera import intrinsics_option

        camera = intrinsics_option(args.intrinsics)
    if args.depth_scale is not None:
        from jaxvo.host.frontend.camera import check_depth_scale_value

        check_depth_scale_value(args.depth_scale, name="--depth-scale")
    return camera


def open_mapped(args: argparse.Namespace, camera):
    """The sequence to map and the trajectory, the depth read as the run read it: ``(seq,
    traj, warnings)``; ``camera``: :func:`_camera`'s. A trajectory jaxvo run wrote names its
    sequence and camera in its first lines (:func:`jaxvo.run.run_header`): one of another
    sequence is refused, and its camera and depth scale are used unless an option gives
    them."""
    from jaxvo.errors import InputError
    from jaxvo.host.frontend.frames import describe
    from jaxvo.host.readers.io import open_sequence
    from jaxvo.run import read_run_header
    from jaxvo.trajectory import read_trajectory

    traj = read_trajectory(args.traj)
    run = read_run_header(args.traj)
    seq = open_sequence(args.sequence, camera=camera, max_diff=args.max_diff,
                        depth_scale=args.depth_scale)
    notes = list(seq.warnings)
    if run is None:
        return seq, traj, notes
    listed = int(getattr(seq, "frames_listed", len(seq)))
    if run["sequence"] != seq.name and (run["frames_listed"], run["first_time"]) != (
            listed, round(float(seq.timestamps[0]), 6)):
        raise InputError(
            f"--traj {args.traj}: jaxvo run wrote it over the sequence {run['sequence']!r} "
            f"({run['frames_listed']} frames listed, its first lines say), not over "
            f"{seq.name!r} ({listed} frames): map it over its own sequence")
    K = run["intrinsics"]
    if camera is None and args.depth_scale is None:
        if K != seq.intrinsics:  # the run was given a camera or depth scale: read as it did
            seq = open_sequence(args.sequence, camera=K, max_diff=args.max_diff,
                                depth_scale=K.depth_scale)
            notes = [w for w in seq.warnings if "overrides" not in w]
            seq.camera_source = f"as jaxvo run read it ({describe(K)}; --traj's first lines)"
    elif seq.intrinsics != K:
        notes.append(f"the camera {describe(seq.intrinsics)} differs from the one jaxvo run "
                     f"read ({describe(K)}, --traj's first lines): the map is not at the "
                     "trajectory's scale unless the run's was wrong")
    return seq, traj, notes


def run(args: argparse.Namespace, prepared: tuple | None = None) -> int:
    from jaxvo.errors import InputError, warn
    from jaxvo.host.writers.mapping import make_maps, map_outputs, mask_reader
    from jaxvo.host.writers.outputs import check_outputs, file_id, output_file, stream_target

    (camera,) = prepared or prepare(args)
    options = map_options(args)
    seq, traj, notes = open_mapped(args, camera)
    options.check(height=seq.height, width=seq.width, names=_NAMES)
    outputs = map_outputs(args.out)
    if args.dynamic_masks is None:
        del outputs["map (nothing left out)"]
    files = {("--out" if k == "map" else f"--out's {k}"): v for k, v in outputs.items()}
    if args.rerun_save:
        files["--rerun-save"] = Path(args.rerun_save)
    files = {what: stream_target(path, what=what) for what, path in files.items()}
    reads = seq.files() + [Path(args.traj)]
    if args.dynamic_masks:
        masks = Path(args.dynamic_masks)
        image_folders = {file_id(p if p.is_dir() else p.parent) for p in seq.files()}
        if file_id(masks) in image_folders:  # TUM names its images by time, as masks are
            raise InputError(f"--dynamic-masks {masks}: holds the sequence's own images, not "
                             "dynamic masks (jaxvo run --dynamic-masks DIR writes those)")
        reads.append(masks)  # every file of it
    check_outputs(reads, files=files)
    for what, path in files.items():
        output_file(path, what=what)
    for note in notes:
        warn(note)
    dynamic = (mask_reader(args.dynamic_masks, shape=(seq.height, seq.width))
               if args.dynamic_masks else None)
    with _logger(args) as logger:
        summary = make_maps(seq, traj, dynamic, options, outputs, where=f"--traj {args.traj}",
                            logger=logger)
    summary.update(camera=getattr(seq, "camera_source", "given"), warnings=notes)
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        _print_summary(summary)
    return 0


def _logger(args: argparse.Namespace):
    """``--rerun-save``'s logger (a context that closes it), or a context holding None."""
    import contextlib

    if not args.rerun_save:
        return contextlib.nullcontext(None)
    from jaxvo.host.writers.recording import RerunLogger, import_rerun

    import_rerun("--rerun-save")
    return RerunLogger(save=args.rerun_save, what="--rerun-save")


def _print_summary(summary: dict) -> None:
    fused, listed = summary["frames_fused"], summary["frames_in_sequence"]
    frames = f"{fused} frames" + (f" of {listed}" if fused != listed else "")
    if summary["masks"]:
        print(f"jaxvo map: {summary['map_points']} points -> {summary['map']} (dynamic pixels "
              f"left out), from {frames}")
        print(f"  beside it  {summary['map_all_points']} points -> {summary['map_all']} "
              "(nothing left out)")
    else:
        print(f"jaxvo map: {summary['map_points']} points -> {summary['map']} (nothing left "
              f"out: no --dynamic-masks), from {frames}")
    if summary["frames_without_mask"]:
        print(f"  left out   {summary['frames_without_mask']} frames without a dynamic "
              "mask (from the static map)")
    print(f"  camera     {summary['camera']}")
    print(f"  picture    {summary['map_picture']}")
