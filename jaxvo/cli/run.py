"""``jaxvo run SEQ_DIR --out traj.txt``: odometry over a recorded TUM-layout sequence.

Frames are processed one at a time by the streaming odometry (pipelined: a frame's device
step runs while the next frame's flow is computed) and every pose is written to the
trajectory file as soon as it is known, so an interrupted run keeps what it computed. The
next frames are read and decoded on other threads meanwhile, and masks and overlays are
encoded and written on another (:mod:`jaxvo.host.prefetch`), so neither waits on the other.
The per-frame step is compiled on the first run on a machine and loaded from the persistent
compile cache afterwards (:mod:`jaxvo.host.compile_cache`); the terminal says when it compiles.
With ``--out-bag`` the results also go to a ROS 2 bag (:mod:`jaxvo.host.bagout`), written on
its own thread and renamed into place once finished.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

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
    from jaxvo.host.camera import PRESETS

    p.epilog = EPILOG + "\n" + EXIT_STATUSES
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("sequence", metavar="SEQ_DIR",
                   help="folder in the TUM RGB-D layout, or a ROS bag (SEQ.bag, or a ROS 2 "
                   "bag folder): colour, depth and camera info, TUM's topics by default; or "
                   "a RealSense Viewer recording (.bag)")
    p.add_argument("--rgb-topic", metavar="TOPIC",
                   help="a bag's colour topic (sensor_msgs/Image; default /camera/rgb/image_color"
                   "; the camera info beside it, e.g. /camera/rgb/camera_info)")
    p.add_argument("--depth-topic", metavar="TOPIC",
                   help="a bag's depth topic (32FC1 metres or 16UC1 millimetres; default "
                   "/camera/depth/image)")
    p.add_argument("--out", "-o", required=True, metavar="FILE",
                   help="trajectory to write (TUM format, camera-to-world; evo reads it); "
                   "'-' writes it to standard output, and the summary to standard error")
    camera = p.add_mutually_exclusive_group()
    camera.add_argument("--camera", metavar="PRESET",
                        help="intrinsics preset (" + ", ".join(sorted(PRESETS)) + "); overrides "
                        "the folder's camera.txt, with a warning where they differ")
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
    # the consecutive-frame window (issue 21) is gone: its option only says what replaced it
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
    from jaxvo.host.bagout import CAMERA_FRAME, STORAGES, WORLD_FRAME

    g.add_argument("--out-bag", metavar="DIR",
                   help="also write a ROS 2 bag (a new folder): the odometry "
                   "(nav_msgs/Odometry), /tf and the dynamic masks, stamped with each frame's "
                   "own time; with --map the static map (PointCloud2) at the end")
    g.add_argument("--bag-storage", choices=STORAGES, help="the bag's storage (default mcap)")
    g.add_argument("--world-frame", metavar="NAME", help=f"the odometry's fixed frame (default {WORLD_FRAME}, "
                   "REP 105; its axes: the first camera's, or the ground truth's)")
    g.add_argument("--camera-frame", metavar="NAME", help="the colour camera's optical frame (default "
                   f"{CAMERA_FRAME}: z forward, x right, y down, REP 103)")
    g.add_argument("--bag-overlay", action="store_true",
                   help="also the image tinted by identifier (/jaxvo/overlay)")
    g.add_argument("--with-input", action="store_true",
                   help="also the input: a bag's every message, or a folder's frames on TUM's "
                   "bag topics, so that one bag replays everything")


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


def _check_options(args: argparse.Namespace):
    """The run's Config and the camera given on the command line (None: the folder's),
    after every option that needs no file is checked (InputError)."""
    import math

    from jaxvo.config import Config, check_config
    from jaxvo.errors import InputError, check_seed
    from jaxvo.host.bagout import check_bag_options
    from jaxvo.host.camera import check_depth_scale_value, intrinsics_option

    if not (math.isfinite(args.max_diff) and args.max_diff >= 0):
        raise InputError(f"--max-diff must be a number of seconds >= 0, got {args.max_diff}")
    if args.frames is not None and args.frames < 2:
        raise InputError(f"--frames must be at least 2 (odometry needs a pair), got {args.frames}")
    if args.depth_scale is not None:
        check_depth_scale_value(args.depth_scale, name="--depth-scale")
    check_seed(args.seed, name="--seed")
    if args.window is not None:
        raise InputError("--window was removed: --keyframes refines a window over the latest "
                         "keyframes instead (Config.keyframe_window of them)")
    cfg = Config(cell=args.cell, num_hypotheses=args.hypotheses,
                 keyframes=Config.keyframes if args.keyframes is None else args.keyframes)
    check_config(cfg, names=_CONFIG_OPTIONS)
    check_bag_options(args)
    camera = args.camera
    if args.intrinsics is not None:
        camera = intrinsics_option(args.intrinsics)
    return cfg, camera


def _open(args: argparse.Namespace, cfg, camera):
    """The sequence, the frames to process and the checked outputs, before any work:
    nothing is written here but the output folders (created)."""
    from jaxvo.config import check_config
    from jaxvo.errors import InputError
    from jaxvo.host.bagout import check_bag_target
    from jaxvo.host.io import STDOUT, check_outputs, open_sequence, output_file, output_folder
    from jaxvo.host.memory import check_memory, run_bytes
    from jaxvo.host.outputs import stream_target

    seq = open_sequence(args.sequence, camera=camera, max_diff=args.max_diff,
                        depth_scale=args.depth_scale, rgb_topic=args.rgb_topic,
                        depth_topic=args.depth_topic)
    n = len(seq) if args.frames is None else min(len(seq), args.frames)
    if n < 2:
        raise InputError(f"{args.sequence}: {n} frame(s); odometry needs at least 2")
    check_config(cfg, height=seq.height, width=seq.width, names=_CONFIG_OPTIONS)
    check_memory(run_bytes(cfg, height=seq.height, width=seq.width),
                 what=f"jaxvo run with {_settings(args)}")
    given = {option: folder for option, folder in (
        ("--masks", args.masks), ("--dynamic-masks", args.dynamic_masks),
        ("--overlays", args.overlays)) if folder}
    out = stream_target(args.out, what="--out", stdout=True)
    files = {} if out == STDOUT else {"--out": out}
    if args.rerun_save:
        files["--rerun-save"] = args.rerun_save
    if args.map:
        from jaxvo.cli.map import map_outputs

        files.update({("--map" if k == "map" else f"--map's {k}"): v
                      for k, v in map_outputs(args.map).items()})
    files = {what: stream_target(path, what=what) for what, path in files.items()}
    bag = {"--out-bag": Path(args.out_bag)} if args.out_bag else {}
    check_outputs(seq.files(), files=files,
                  folders={**{k: Path(v) for k, v in given.items()}, **bag})
    if args.out_bag:
        check_bag_target(args.out_bag)
    for what, path in files.items():
        output_file(path, what=what)
    if args.rerun or args.rerun_save:
        from jaxvo.host.recording import check_display, import_rerun

        import_rerun("--rerun" if args.rerun else "--rerun-save")
        if args.rerun:
            check_display("--rerun")
    names = {f"{t:.6f}.png" for t in seq.timestamps[:n]}
    folders = {option: output_folder(folder, what=option, names=names)
               for option, folder in given.items()}
    return seq, n, out, folders


def _settings(args: argparse.Namespace) -> str:
    """The shape-setting options as given, for messages."""
    return f"--hypotheses {args.hypotheses}, --cell {args.cell}"


def prepare(args: argparse.Namespace):
    """Every option and file checked, the sequence opened and the outputs made ready, before
    JAX loads: ``(cfg, seq, n, out, folders)`` for :func:`run`."""
    cfg, camera = _check_options(args)
    return (cfg, *_open(args, cfg, camera))


def run(args: argparse.Namespace, prepared=None) -> int:
    import contextlib
    import itertools
    import warnings as py_warnings

    from jaxvo.cli.main import EXIT_INTERRUPTED, EXIT_NOTHING_ESTIMATED, interrupt_at_safe_points
    from jaxvo.cli.map import run_header
    from jaxvo.host.bagout import open_bag
    from jaxvo.host.compile_cache import announce_compile
    from jaxvo.host.io import DepthScaleWarning, TrajectoryWriter, check_depth_scale, first_readable
    from jaxvo.host.prefetch import BackgroundWriter, read_ahead
    from jaxvo.host.progress import Progress

    cfg, seq, n, out, folders = prepared or prepare(args)
    # JAX's pipeline loads once the input is known to be usable: a one-line error waits
    # for no heavy import
    from jaxvo.odometry import Odometry, choose_start_pose

    warnings = list(seq.warnings)
    # frames are read and decoded ahead on a small thread pool, beside the flow and the step
    reads = read_ahead(seq.__getitem__, range(n))
    # the first readable frame: its depth tells a wrong depth scale, its time the start pose
    first, early = first_readable(((i, fut.result) for i, fut in reads), where=args.sequence,
                                  total=n)
    note = check_depth_scale(first.depth, seq.intrinsics,
                             where=f"{args.sequence} frame {first.index}",
                             raw_units=not getattr(seq, "float_depth", False))
    warnings += [note] if note else []
    for w in warnings:
        print(f"jaxvo: warning: {w}", file=sys.stderr)
    gt = seq.groundtruth
    T_w_c0, start = choose_start_pose(args.start_pose or "gt", gt, first.timestamp,
                                      max_diff=args.max_diff, required=bool(args.start_pose))
    odo = Odometry(seq.intrinsics, cfg=cfg, seed=args.seed, T_w_c0=T_w_c0)
    progress = Progress("jaxvo run", n - 1, enabled=not args.quiet)
    # the recording and the bag are whole once the run and its map are (the recording
    # closed last); an error discards both, and an earlier recording stays
    with _logger(args, odo, gt) as logger, open_bag(args, seq) as bag:
        # leaving this block, also by Ctrl-C, closes the reader, writes every image queued,
        # then puts the trajectory file in place (whole, with every pose computed)
        with (TrajectoryWriter(out, comment=run_header(args.sequence, seq)) as writer,
              interrupt_at_safe_points() as stop,
              BackgroundWriter() as images,
              contextlib.closing(reads),
              announce_compile("the per-frame step", stream=None if args.quiet else sys.stderr)
              as compiling,
              py_warnings.catch_warnings()):
            py_warnings.simplefilter("ignore", DepthScaleWarning)  # said above, with the frame
            rec = _Recorder(cfg, writer, images, folders, keep_dynamic=bool(args.map), bag=bag)
            rec.process(odo, itertools.chain(early, ((i, fut.result) for i, fut in reads)),
                        stop, progress)
        progress.close()
        summary = _summary(args, seq, n, start, rec, compiling, warnings, out)
        # a Ctrl-C after the last frame: no map; the bag finished with every frame, as the
        # trajectory was put in place with every pose; then the run says it was interrupted
        if args.map:
            rec.interrupted = rec.interrupted or stop.requested
            summary.update(_map(args, seq, n, rec, out, writer, logger))
        if bag is not None:
            summary.update(bag.finish())
        if args.map or bag is not None:
            summary["interrupted"] = rec.interrupted = rec.interrupted or stop.requested
    if gt is not None and rec.written >= 3:
        summary.update(_scores(gt, out, writer, args.max_diff))
    # the trajectory on standard output (--out -): the summary goes beside the warnings
    stream = sys.stderr if str(out) == "-" else sys.stdout
    with contextlib.redirect_stdout(stream):
        if args.json:
            print(json.dumps(summary, indent=1))
        else:
            _print_summary(summary, n, rec.interrupted)
    if rec.interrupted:
        print("jaxvo: interrupted; the poses computed so far are in the trajectory file",
              file=sys.stderr)
        return stop.exit_status if stop.requested else EXIT_INTERRUPTED
    if rec.pairs_ok == 0:
        print("jaxvo: no frame pair gave a camera motion (every pair skipped or dropped, see "
              "the summary)", file=sys.stderr)
        return EXIT_NOTHING_ESTIMATED
    return 0


def _logger(args: argparse.Namespace, odo, gt):
    """The run's Rerun logger attached to ``odo`` (a context that closes it), or a context
    holding None."""
    import contextlib

    if not (args.rerun or args.rerun_save):
        return contextlib.nullcontext(None)
    from jaxvo.host.recording import RerunLogger

    logger = RerunLogger(save=args.rerun_save, spawn=args.rerun, what="--rerun-save")
    odo.attach(logger)
    logger.log_groundtruth(gt)
    return logger


class _Recorder:
    """What a run does with each frame's result: the pose to the trajectory file, the
    pair's images to the writer thread, and the counts the summary gives."""

    def __init__(self, cfg, writer, images, folders: dict, *, keep_dynamic: bool = False,
                 bag=None):
        from collections import Counter

        self.cfg, self.writer, self.images, self.folders = cfg, writer, images, folders
        self.bag = bag  # a BagWriter (--out-bag), written on the writer thread as the images
        self.skipped: Counter[str] = Counter()
        self.dropped: Counter[str] = Counter()
        self.times: list[float] = []
        self.written = 0
        self.pairs_ok = 0
        self.recent: dict[int, object] = {}  # submitted frames whose results are not out yet
        self.anchor = None  # the last kept frame: the next pair's labels lie on its image
        self.last_moving = None  # the last pair's mask cells, for the last frame's mask
        self.reacquired = 0  # pairs in which the background took its identifier back
        self.keyframes = 1 if cfg.keyframes else 0  # keyframes taken (the first frame is one)
        self.first_unreadable = ""  # the first unreadable frame's error, for the summary
        self.interrupted = False
        self.seen = 0  # frames taken from the sequence (read, or found unreadable)
        # frame index -> its dynamic cells (n,) bool, for --map; None: not kept
        self.dynamic: dict[int, object] | None = {} if keep_dynamic else None

    def process(self, odo, frames, stop, progress) -> None:
        """Every frame of ``frames`` ((index, read) pairs) through ``odo``, pipelined;
        Ctrl-C (taken by ``stop`` between frames) ends the loop with what was computed."""
        import time

        from jaxvo.errors import InputError

        try:
            submitted = 0
            for i, read in frames:
                stop()  # Ctrl-C is taken here, between frames, never inside a compile
                t0 = time.perf_counter()
                self.seen += 1
                try:
                    frame = read()
                except InputError as exc:  # unreadable frame: drop it, keep going
                    self.dropped["unreadable frame"] += 1
                    self.first_unreadable = self.first_unreadable or str(exc)
                    continue
                self.recent[submitted] = frame
                submitted += 1
                # pipelined: this frame's device step runs while the next one is read
                # and its flow computed; the result that comes back is the previous one's
                r = odo.submit(frame.bgr, frame.depth, frame.timestamp)
                if r is not None:
                    self.record(r)
                self.times.append(time.perf_counter() - t0)  # reading and writing included
                if i:
                    progress(i)
        except KeyboardInterrupt:
            self.interrupted = True
        self.finish(odo)

    def finish(self, odo) -> None:
        """The last frame's result (also after an interruption) and the last frame's
        dynamic mask."""
        r = odo.flush()
        if r is not None:
            self.record(r)
        if (self.dynamic is not None and self.last_moving is not None
                and self.anchor is not None):
            self.dynamic[self.anchor.index] = self.last_moving
        if (("--dynamic-masks" in self.folders or self.bag is not None)
                and self.last_moving is not None and self.anchor is not None):
            # the last kept frame has no pair of its own: it takes the last label map
            self.images.submit(self.write_images, self.anchor, None, self.last_moving)

    def record(self, r) -> None:
        """One finished frame: its pose now (a line, flushed: a second Ctrl-C, which ends
        the process at once, loses none), its pair's images on the writer thread."""
        from jaxvo.status import Status

        frame = self.recent.pop(r.index)
        if self.bag is not None and self.bag.input_frames:
            self.images.submit(self.bag.write_frame, frame)
        if r.dropped is not None:
            self.dropped[r.dropped] += 1
            return
        self.writer.write(r.timestamp, r.T_w_c)
        if self.bag is not None:
            self.images.submit(self.bag.write_pose, frame.index, r.T_w_c)
        self.written += 1
        prev_frame, self.anchor = self.anchor, frame
        if r.output is None or prev_frame is None:
            return
        if r.status == Status.OK:
            self.pairs_ok += 1
        else:
            self.skipped[r.status.reason] += 1
        self.reacquired += int(r.output.reacquired)
        if r.output.keyframes is not None:
            self.keyframes = int(r.output.keyframes)
        self.last_moving = r.output.dynamic
        if self.dynamic is not None:
            self.dynamic[prev_frame.index] = self.last_moving
        if self.folders or self.bag is not None:
            self.images.submit(self.write_images, prev_frame, r, self.last_moving)

    def write_images(self, frame, r, moving) -> None:
        """The images of a pair whose labels lie on ``frame``'s image, named by its time as
        TUM names its images; ``r`` None: the dynamic mask ``moving`` alone. Runs on the
        writer thread: encoding PNGs is most of what a frame's output costs."""
        import numpy as np

        from jaxvo.host.io import write_image
        from jaxvo.host.masks import dynamic_pixels, grid_to_pixels, overlay_panel
        from jaxvo.host.plugin import mask_png

        h, w = frame.depth.shape
        cell = self.cfg.cell
        name = f"{frame.timestamp:.6f}.png"
        if "--masks" in self.folders and r is not None:
            ids = grid_to_pixels(r.ids, h, w, cell).astype(np.uint8)
            write_image(self.folders["--masks"] / name, ids)
        mask = mask_png(dynamic_pixels(moving, h, w, cell))  # plugin: step k labels image k
        if "--dynamic-masks" in self.folders:
            write_image(self.folders["--dynamic-masks"] / name, mask)
        if self.bag is not None:
            self.bag.write_mask(frame, mask, None if r is None else r.output)
        if "--overlays" in self.folders and r is not None:
            write_image(self.folders["--overlays"] / name,
                        overlay_panel(frame.bgr, r.output, cell))


def _map(args, seq, n: int, rec: _Recorder, out, writer, logger) -> dict:
    """``--map``: the maps from the trajectory written and the run's dynamic cells, as
    ``jaxvo map`` makes them with its default options; the summary's part (why there is no
    map, after Ctrl-C or with no pose)."""
    if rec.interrupted or not rec.written:
        why = "the run was interrupted" if rec.interrupted else "no pose was written"
        kept = f" (an earlier {args.map} is as it was)" if Path(args.map).exists() else ""
        return {"map_not_written": why + kept}
    from types import SimpleNamespace

    from jaxvo.cli.map import make_maps, map_outputs
    from jaxvo.host.mapping import GROW, VOTE_SHARE, VOTE_VOXEL
    from jaxvo.host.masks import dynamic_pixels

    def dynamic(index: int, timestamp: float):
        cells = rec.dynamic.get(index)
        return None if cells is None else dynamic_pixels(cells, seq.height, seq.width,
                                                         rec.cfg.cell)

    options = SimpleNamespace(max_diff=args.max_diff, voxel=0.02, max_depth=4.0, grow=GROW,
                              vote_voxel=VOTE_VOXEL, vote_share=VOTE_SHARE)
    est = writer.written()  # as the file holds it, whoever replaced the file since
    on_static = None if rec.bag is None else (
        lambda static: rec.bag.write_map(static, rec.anchor.index))
    return make_maps(seq, est, dynamic, options, map_outputs(args.map),
                     where=f"--out {out}", frames=n, logger=logger, on_static=on_static)


def _summary(args, seq, n: int, start: str, rec: _Recorder, compiling, warnings, out) -> dict:
    """The run's summary (printed as a table, or as JSON with --json)."""
    times = rec.times
    steady = times[2:] if len(times) > 3 else times[1:]
    fps = len(steady) / sum(steady) if steady and sum(steady) > 0 else 0.0
    return {
        "sequence": str(args.sequence),
        "frames_listed": getattr(seq, "frames_listed", len(seq)),
        "frames": n,
        "frames_processed": rec.seen,
        "camera": getattr(seq, "camera_source", "given"),
        "start_pose": start,
        "poses_written": rec.written,
        "keyframes": rec.keyframes,  # 0: frame to frame only (Config.keyframes off)
        "trajectory": str(out),
        "frames_per_second": round(fps, 2),
        "first_frame_pair_seconds": round(times[1], 3) if len(times) > 1 else None,
        # the step's compile (or its load from the persistent compile cache), seconds
        "compile": [{"seconds": round(c.seconds, 3), "from_cache": c.from_cache}
                    for c in compiling],
        "pairs_ok": rec.pairs_ok,
        "skipped": dict(rec.skipped),
        "background_reacquired": rec.reacquired,
        "dropped": {(f"{k} (first: {rec.first_unreadable})" if k == "unreadable frame" else k):
                    v for k, v in rec.dropped.items()},
        "warnings": warnings,
        "interrupted": rec.interrupted,
        "peak_rss_mib": _peak_rss_mib(),
    }


def _scores(gt, out, writer, max_diff: float) -> dict:
    """ATE and RPE of the written trajectory against the folder's ground truth, or why
    they could not be computed: the file as ``jaxvo eval`` reads it, or the poses the
    writer wrote where they went to standard output."""
    import numpy as np

    from jaxvo.errors import InputError
    from jaxvo.evaluation.metrics import ate, rpe

    est = writer.written()  # as the file holds it, whoever replaced the file since
    # a camera that never moves (a fixed camera) defines no alignment: compared as it is,
    # from the true first pose (as jaxvo.evaluation.scores.trajectory_scores does)
    aligned = bool(np.ptp(np.asarray(gt.poses)[:, :3, 3], axis=0).max() > 1e-6)
    try:
        a = ate(gt, est, align=aligned, max_diff=max_diff)
        r1 = rpe(gt, est, delta=1, delta_unit="frames", max_diff=max_diff)
    except InputError as exc:  # e.g. every pose carried: nothing to align
        return {"scores_not_computed": str(exc)}
    return {"ate_rmse_m": round(a.stats.rmse, 5), "ate_aligned": aligned,
            "rpe_trans_rmse_m_per_frame": round(r1.trans.rmse, 5),
            "rpe_rot_rmse_deg_per_frame": round(r1.rot.rmse, 4)}


def _print_summary(summary: dict, n: int, interrupted: bool) -> None:
    where = "standard output" if summary["trajectory"] == "-" else summary["trajectory"]
    print(f"jaxvo run: {summary['poses_written']} poses -> {where}"
          + (" (interrupted)" if interrupted else ""))
    compiles = summary["compile"]
    how = ("the step loaded from the compile cache" if compiles and all(
        c["from_cache"] for c in compiles) else "compile included")
    print(f"  speed      {summary['frames_per_second']:.1f} frames/s steady state, reading and "
          f"writing included (first pair {summary['first_frame_pair_seconds']} s, {how})")
    print(f"  camera     {summary['camera']}")
    print(f"  start pose {summary['start_pose']}")
    if summary["keyframes"]:
        print(f"  keyframes  {summary['keyframes']} taken (each frame's motion also fitted to "
              "the latest keyframe's static points; the last keyframes refined together as "
              "each was taken)")
    listed, seen = summary["frames_listed"], summary["frames_processed"]
    print(f"  frames     {seen} processed" + (f" of {n}" if seen != n else "")
          + (f" ({listed} listed)" if listed != n else ""))
    for label, counts, unit in (("dropped", summary["dropped"], "frames"),
                                ("skipped", summary["skipped"], "frame pairs")):
        total = sum(counts.values())
        what = unit if total != 1 else unit[:-1]  # "1 frame", "2 frame pairs"
        print(f"  {label:<10} {total} {what}" + (" (no pose)" if label == "dropped" and total
                                                  else " (the last motion carried)" if total else ""))
        for reason, count in sorted(counts.items(), key=lambda kv: -kv[1]):
            print(f"    {count:5d}  {reason}")
    print(f"  background re-acquired in {summary['background_reacquired']} frame pairs (the "
          "segment the evidence gave the background had another identifier)")
    print(f"  memory     {summary['peak_rss_mib']:.0f} MiB peak resident")
    for w in summary["warnings"]:
        print(f"  warning    {w}")
    if "scores_not_computed" in summary:
        print(f"  ATE / RPE  not computed: {summary['scores_not_computed']}")
    if "map_not_written" in summary:
        print(f"  map        not written: {summary['map_not_written']}")
    if "map" in summary:
        print(f"  map        {summary['map_points']} points -> {summary['map']} (dynamic pixels "
              f"left out), {summary['map_all_points']} -> {summary['map_all']} (nothing left "
              f"out), picture {summary['map_picture']}")
    if "bag" in summary:
        print(f"  bag        {summary['bag_messages']} messages on {summary['bag_topics']} topics "
              f"-> {summary['bag']}" + (f" ({summary['bag_input_messages']} of them the "
                                        "input's)" if summary["bag_input_messages"] else ""))
    if "ate_rmse_m" in summary:
        how = "aligned" if summary["ate_aligned"] else "not aligned: the camera does not move"
        print(f"  ATE        {summary['ate_rmse_m']:.4f} m rmse ({how}, ground truth in folder)")
        print(f"  RPE        {summary['rpe_trans_rmse_m_per_frame']:.4f} m, "
              f"{summary['rpe_rot_rmse_deg_per_frame']:.3f} deg rmse per frame")
