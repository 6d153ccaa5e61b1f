"""``jaxvo run SEQ_DIR --out traj.txt``: odometry over a recorded TUM-layout sequence.

Argument handling and printing over the library's run (:mod:`jaxvo.run`:
:func:`~jaxvo.run.prepare_run` checks everything before JAX loads,
:func:`~jaxvo.run.record_run` runs the streaming odometry and records every output),
as evo's ``main_ape.py`` is over ``ape()``. The per-frame step is compiled on the first run
on a machine and loaded from the persistent compile cache afterwards
(:mod:`jaxvo.host.services.compile_cache`); the terminal says when it compiles.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING

from jaxvo.cli.inputs import require_sequence
from jaxvo.cli.later import Later
from jaxvo.errors import InputError

if TYPE_CHECKING:
    from jaxvo.run import PreparedRun, RunOptions

# command-line option -> the Config field it sets (named so in error messages)
_CONFIG_OPTIONS = {"cell": "--cell", "num_hypotheses": "--hypotheses"}

EPILOG = """\
examples:
  jaxvo run rgbd_dataset_freiburg3_walking_xyz --out traj.txt
  jaxvo run SEQ_DIR --out traj.txt --camera tum_fr3 --dynamic-masks dyn/ --overlays over/
  evo_ape tum SEQ_DIR/groundtruth.txt traj.txt -a

input: SEQ_DIR in the TUM RGB-D layout: rgb.txt and depth.txt ('timestamp filename'),
  or associations.txt ('t_rgb rgb t_depth depth'); optional groundtruth.txt (TUM
  trajectory) and camera.txt (lines 'fx 535.4', 'fx: 535.4' or 'fx = 535.4' for fx fy cx
  cy in pixels and depth_scale in raw units per metre, default 5000). Lines out of time
  order are sorted and repeated timestamps dropped, with a warning. Or a ROS bag (ROS 1
  SEQ.bag, or a ROS 2 bag folder): --rgb-topic and --depth-topic (TUM's topics by default),
  paired by header stamp within --max-diff; the camera from the camera_info beside the
  colour topic unless --camera. A RealSense Viewer recording (.bag): its Color and Depth
  streams, cameras, depth units and extrinsics found, the depth registered to colour.

camera: --camera or --intrinsics, else camera.txt, else ETH3D's calibration.txt ('fx fy cx
  cy'), else the folder's name as the TUM and Bonn benchmarks name their downloads
  (rgbd_dataset_freiburg3_*, rgbd_bonn_*); --depth-scale overrides the depth scale. A
  negative fy (ICL-NUIM) is a camera whose y axis points up. Depth: 16-bit PNG in raw
  units, or float metres in 32-bit float TIFF or .npy files.

refused before any work: outputs over what the run reads (--masks SEQ_DIR/rgb) or over
  each other (two options, one folder), and settings that need more memory than the
  machine has (--hypotheses).

output: the trajectory is camera-to-world in TUM format, one pose per frame kept, written
  as it is computed. A frame that cannot be used (unreadable, or too few valid flow
  vectors with the last good frame: black, saturated, noise) is dropped and gets no pose;
  the next frame pairs with the last good one. Masks and overlays are PNG files named by
  the frame's RGB timestamp (e.g. 1305031102.175304.png, as TUM names its images), one per
  frame kept, the labels of the frame pair that starts at that image. An overlay is 4
  panels side by side at half size (1280x240 for 640x480 images): Model (the image tinted
  by temporal identifier: grey-blue static, colours moving objects), Hypotheses (best raw
  motion hypothesis per cell), Segments (spatial segments) and Group (segments after
  label matching), as thesis Fig. 5.1. --out-bag writes a new ROS 2 bag folder (MCAP):
  /jaxvo/odometry, /tf (odom -> camera_optical_frame), /jaxvo/dynamic_mask and its
  /jaxvo/camera_info, stamped with each frame's own time (docs/ros.md).
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from jaxvo.cli.main import EXIT_STATUSES, add_seed_option, add_summary_options

    p.epilog = EPILOG + "\n" + EXIT_STATUSES
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("sequence", metavar="SEQ_DIR",
                   help="folder in the TUM RGB-D layout, or a ROS bag (SEQ.bag, or a ROS 2 "
                   "bag folder): colour, depth and camera info, TUM's topics by default; or "
                   "a RealSense Viewer recording (.bag)")
    for flag, topic in (("--rgb-topic", ("colour topic (sensor_msgs/Image; default "
                                         "/camera/rgb/image_color; the camera info beside "
                                         "it, e.g. /camera/rgb/camera_info)")),
                        ("--depth-topic", ("depth topic (32FC1 metres or 16UC1 millimetres; "
                                           "default /camera/depth/image)"))):
        p.add_argument(flag, metavar="TOPIC", help=f"a bag's {topic}")
    p.add_argument("--out", "-o", required=True, metavar="FILE",
                   help="trajectory to write (TUM format, camera-to-world; evo reads it); "
                   "'-' writes it to standard output, and the summary to standard error")
    camera = p.add_mutually_exclusive_group()
    presets = camera.add_argument(
        "--camera", metavar="PRESET|FILE", help="intrinsics preset (%(presets)s) or a camera "
        "file (a camera.txt, an OpenCV calibration YAML with its distortion); overrides the "
        "folder's camera.txt, with a warning where they differ")
    presets.presets = Later("jaxvo.host.frontend.camera", "PRESETS", lambda d: ", ".join(sorted(d)))
    camera.add_argument("--intrinsics", metavar="FX,FY,CX,CY",
                        help="the camera's intrinsics in pixels (a negative FY: a camera whose "
                        "y axis points up, as ICL-NUIM's); overrides camera.txt like --camera")
    p.add_argument("--depth-scale", type=float, metavar="UNITS",
                   help="raw depth units per metre of the 16-bit depth images (TUM 5000, "
                   "millimetres 1000); overrides the camera's (a bag's 16UC1 depth: "
                   "millimetres unless given)")
    p.add_argument("--max-diff", type=float, default=0.02, metavar="S",
                   help="largest rgb/depth (and ground-truth) timestamp difference when "
                   "associating, seconds (default 0.02)")
    p.add_argument("--frames", type=int, metavar="N",
                   help="process only the first N frames (default all)")
    add_seed_option(p, "PRNG seed of the hypothesis sampling")
    p.add_argument("--cell", type=int, default=16,
                   help="grid cell size in pixels, at least 4 (default 16)")
    p.add_argument("--hypotheses", type=int, default=20,
                   help="motion hypotheses per frame pair, H, at least 1 (default 20)")
    # the consecutive-frame window is gone: its option only says what replaced it
    p.add_argument("--window", help=argparse.SUPPRESS)
    p.add_argument("--keyframes", action=argparse.BooleanOptionalAction, default=None,
                   help="also fit each frame's motion to the latest keyframe's static points, and "
                   "refine the last keyframes' poses and points together whenever a keyframe is "
                   "taken, so that drift accrues per keyframe, not per frame (default: "
                   "Config.keyframes, off; the summary says how many keyframes were taken)")
    p.add_argument("--start-pose", choices=("gt", "identity"),
                   help="first pose of the trajectory: 'gt' the ground-truth pose of the first "
                   "frame (groundtruth.txt, within --max-diff), or 'identity' (default: gt where "
                   "there is one, else identity; the summary says which)")
    for flag, images in (  # the folders of per-frame images (see "output" below)
            ("--masks", "label masks (PNG, pixel value = identifier, 1 = static)"),
            ("--dynamic-masks", (
                "dynamic-pixel masks (PNG, 255 = dynamic, 0 = static) for other odometry to "
                "ignore; the last frame takes the last pair's labels. A cell is dynamic once its "
                "evidence of moving has built up over frames, so the first frame's mask is empty "
                "(its overlay's Segments panel shows the motions measured there)")),
            ("--overlays", "overlay panels of the labels (PNG, see below)")):
        p.add_argument(flag, metavar="DIR", help=f"write per-frame {images}")
    p.add_argument("--rerun", action="store_true",
                   help="open the Rerun viewer and show the run as it goes: images, labels, "
                   "depth, 3D points, the camera and its path, the per-frame numbers (needs a "
                   "display, and pip install 'jaxvo[viz]')")
    p.add_argument("--rerun-save", metavar="FILE.rrd",
                   help="write the same as a Rerun recording (headless; open it with `rerun "
                   "FILE.rrd` anywhere; pip install 'jaxvo[viz]')")
    p.add_argument("--map", metavar="FILE.ply",
                   help="after the run, fuse the depth into a static map with the dynamic "
                   "pixels left out, as jaxvo map does (FILE_all.ply: nothing left out; "
                   "FILE.png: both pictured); the map's options are jaxvo map's defaults")
    _add_bag_arguments(p.add_argument_group("ROS 2 bag output (docs/ros.md)"))
    add_summary_options(p, summary="the summary",
                        quiet="no progress line, and no line saying that the step compiles")


def _add_bag_arguments(g) -> None:
    g.add_argument("--out-bag", metavar="DIR",
                   help="also write a ROS 2 bag (a new folder): the odometry "
                   "(nav_msgs/Odometry), /tf and the dynamic masks, stamped with each frame's "
                   "own time; with --map the static map (PointCloud2) at the end")
    g.add_argument("--bag-storage", choices=Later("jaxvo.host.writers.bagout", "STORAGES"),
                   metavar="STORAGE",
                   help="the bag's storage: %(choices)s (default mcap)")
    world = g.add_argument(
        "--world-frame", metavar="NAME", help="the odometry's fixed frame (default "
        "%(frame)s, REP 105; its axes: the first camera's, or the ground truth's)")
    world.frame = Later("jaxvo.host.writers.bagout", "WORLD_FRAME")
    camera = g.add_argument(
        "--camera-frame", metavar="NAME", help="the colour camera's optical frame (default "
        "%(frame)s: z forward, x right, y down, REP 103)")
    camera.frame = Later("jaxvo.host.writers.bagout", "CAMERA_FRAME")
    g.add_argument("--bag-overlay", action="store_true",
                   help="also the image tinted by identifier (/jaxvo/overlay)")
    g.add_argument("--with-input", action="store_true",
                   help="also the input: a bag's every message, or a folder's frames on TUM's "
                   "bag topics, so that one bag replays everything")


def options(args: argparse.Namespace) -> RunOptions:
    """The run the command line asks for (the options that need no file checked later, by
    :func:`jaxvo.run.prepare_run`)."""
    from jaxvo.config import Config
    from jaxvo.host.frontend.camera import intrinsics_option
    from jaxvo.host.writers.bagout import BagOptions
    from jaxvo.run import RunOptions

    if args.window is not None:
        raise InputError("--window was removed: --keyframes refines a window over the latest "
                         "keyframes instead (Config.keyframe_window of them)")
    cfg = Config(cell=args.cell, num_hypotheses=args.hypotheses,
                 keyframes=Config.keyframes if args.keyframes is None else args.keyframes)
    camera = intrinsics_option(args.intrinsics) if args.intrinsics is not None else args.camera
    bag = BagOptions(args.out_bag, args.bag_storage, args.world_frame, args.camera_frame,
                     args.bag_overlay, args.with_input)
    return RunOptions(
        args.sequence, args.out, cfg, seed=args.seed, camera=camera,
        depth_scale=args.depth_scale, max_diff=args.max_diff, frames=args.frames,
        start_pose=args.start_pose, rgb_topic=args.rgb_topic, depth_topic=args.depth_topic,
        masks=args.masks, dynamic_masks=args.dynamic_masks, overlays=args.overlays,
        rerun=args.rerun, rerun_save=args.rerun_save, map=args.map, bag=bag,
        quiet=args.quiet)


def prepare(args: argparse.Namespace) -> PreparedRun:
    """Every option and file checked, the sequence opened and the outputs made ready, before
    JAX loads (:func:`run` takes it). A SEQ_DIR that does not exist is said first, before
    NumPy loads (a bag's topics given: the bag reader's to say), then an --out that is a
    folder, lies in a folder that is not there (and that no output folder makes) or is
    standard output where it cannot go, before the options and the sequence are checked
    (with one of those wrong too, the --out is said first); the rest, what --out must not
    overwrite included, by :func:`jaxvo.run.prepare_run`."""
    from jaxvo.host.writers.outputs import file_target

    if not (args.rgb_topic or args.depth_topic):
        require_sequence(args.sequence)
    file_target(args.out, what="--out", stdout=True, folders=[f for f in (
        args.masks, args.dynamic_masks, args.overlays, args.out_bag) if f])
    from jaxvo.run import prepare_run

    return prepare_run(options(args), names=_CONFIG_OPTIONS)


def run(args: argparse.Namespace, prepared: PreparedRun | None = None) -> int:
    from jaxvo.cli.main import EXIT_INTERRUPTED, EXIT_NOTHING_ESTIMATED, interrupt_at_safe_points
    from jaxvo.run import record_run, summary_lines

    prepared = prepared or prepare(args)
    with interrupt_at_safe_points() as stop:  # main()'s, where main() runs the command
        summary = record_run(prepared, stop=stop)
    # the trajectory on standard output (--out -): the summary goes beside the warnings
    stream = sys.stderr if summary["trajectory"] == "-" else sys.stdout
    print(json.dumps(summary, indent=1) if args.json else "\n".join(summary_lines(summary)),
          file=stream)
    if summary["interrupted"]:
        print("jaxvo: interrupted; the poses computed so far are in the trajectory file",
              file=sys.stderr)
        return stop.exit_status if stop.requested else EXIT_INTERRUPTED
    if summary["pairs_ok"] == 0:
        print("jaxvo: no frame pair gave a camera motion (every pair skipped or dropped, see "
              "the summary)", file=sys.stderr)
        return EXIT_NOTHING_ESTIMATED
    return 0
