"""``jaxvo demo``: synthesise a dynamic scene, run jaxvo and its peers on it, score them.

Needs no download: the scene comes from the built-in seeded generator, with exact ground
truth for the camera and for which pixels move.
"""

from __future__ import annotations

import argparse
import json
from typing import Any, NamedTuple

PEERS = "opencv_rgb,opencv_rgbd"  # the peers a demo compares with unless told



def add_arguments(p: argparse.ArgumentParser) -> None:
    from jaxvo.cli.main import add_seed_option, add_summary_options

    p.add_argument("--scenario", default="fixed_camera_2",
                   help="synthetic scenario (see `jaxvo synth --help`; default fixed_camera_2)")
    p.add_argument("--frames", type=int, default=90, help="frames to synthesise (default 90)")
    add_seed_option(p, "seed of the scene and of the sampling")
    p.add_argument("--peers", default=PEERS, help="comma-separated peers to compare with, "
                   f"'all' or 'none' (default {PEERS})")
    p.add_argument("--out", metavar="DIR",
                   help="also write the trajectories (TUM format) and a few overlay panels "
                   "(PNG named by timestamp, see `jaxvo run --help`) here (created)")
    add_summary_options(p, summary="the scores", quiet="no progress lines")


def _peer_list(text: str) -> list[str]:
    from jaxvo.errors import InputError
    from jaxvo.host.services.peers import available_peers

    names = available_peers()
    if text == "none":
        return []
    if text == "all":
        return names
    chosen = [s.strip() for s in text.split(",") if s.strip()]
    bad = [s for s in chosen if s not in names]
    if bad:
        raise InputError(f"unknown peer(s) {', '.join(bad)}; available: {', '.join(names)}")
    return chosen


class _Anchors:
    """The images a run's frame pairs label (``SequenceResult.frames[:-1]``), indexed by
    pair: what :func:`jaxvo.evaluation.scores.segmentation_scores` reads, also when frames were
    dropped."""

    def __init__(self, seq, frames):
        self.name, self._seq, self._frames = seq.name, seq, frames

    def __getitem__(self, k: int):
        return self._seq[int(self._frames[k])]


def _check_options(args: argparse.Namespace) -> None:
    """The options whose checks need no NumPy: the scenario's name, the frame count and the
    seed, answered before it loads."""
    from jaxvo.cli.synth import check_scenario
    from jaxvo.errors import InputError, check_seed

    check_scenario(args.scenario)
    if args.frames < 2:
        raise InputError(f"--frames must be at least 2, got {args.frames}")
    check_seed(args.seed, name="--seed")


def _check(args: argparse.Namespace, cfg) -> tuple[list[str], object]:
    """The peers and the output folder (None without --out), after every option is checked
    and the run is known to fit in memory, before any work."""
    from pathlib import Path

    from jaxvo.host.services.memory import (
        FRAME_BYTES_PER_PIXEL,
        SYNTH_BYTES_PER_FRAME,
        check_memory,
        run_bytes,
    )
    from jaxvo.host.writers.outputs import check_outputs, output_folder

    peers = _peer_list(args.peers)  # its module loads OpenCV (and tries Open3D) to say which run
    # the frames are rendered into memory, then scanned whole
    check_memory(run_bytes(cfg, height=480, width=640, frames=args.frames, host_bytes=(
        SYNTH_BYTES_PER_FRAME + FRAME_BYTES_PER_PIXEL * 480 * 640) * args.frames),
        what=f"jaxvo demo --frames {args.frames}")
    if not args.out:
        return peers, None
    # one file per method (a peer named twice: one file twice), and the overlays
    methods = ("jaxvo", "groundtruth", *peers)
    check_outputs((), files={f"the {name} trajectory (#{k + 1})": Path(args.out) / f"{name}.txt"
                             for k, name in enumerate(methods)})
    return peers, output_folder(args.out, what="--out")


def prepare(args: argparse.Namespace):
    """The options checked and the output folder made, before JAX loads: ``(cfg, peers,
    out)`` for :func:`run`. :func:`_check_options`' answers come before NumPy loads, and
    so does an --out that is a file: said before the peers (whose module loads OpenCV) and
    the memory are checked, with two things wrong the --out first."""
    from jaxvo.config import Config
    from jaxvo.host.writers.outputs import folder_target

    _check_options(args)
    if args.out:
        folder_target(args.out, what="--out")
    cfg = Config()
    return (cfg, *_check(args, cfg))


def run(args: argparse.Namespace, prepared=None) -> int:
    from jaxvo.cli.main import interrupt_at_safe_points
    from jaxvo.evaluation.scores import trajectory_scores
    from jaxvo.host.readers.io import InMemorySequence, write_trajectory
    from jaxvo.host.services.peers import run_peer
    from jaxvo.host.services.progress import Progress
    from jaxvo.synth.scenes import make_sequence

    cfg, peers, out = prepared or prepare(args)
    say = (lambda *a: None) if args.json else print
    quiet = args.quiet or args.json
    with interrupt_at_safe_points() as stop:

        def progress(label: str):
            """A progress line whose every update is also a safe point to stop at."""
            line = Progress(label, enabled=not quiet)

            def update(done: int, total: int) -> None:
                stop()
                line(done, total)

            return update

        say(f"jaxvo demo: scenario {args.scenario}, {args.frames} frames 640x480, seed {args.seed}")
        # rendered once up front, so that every method is timed on the same frames in memory
        seq = InMemorySequence(make_sequence(args.scenario, frames=args.frames, seed=args.seed))
        stop()
        ours = _run_jaxvo(seq, cfg, args.seed, progress("  grid flow"))
        stop()
        rows = {"jaxvo": ours.row}
        for name in peers:
            stop()
            run = run_peer(seq, name, progress=progress(f"  {name}"))
            rows[name] = trajectory_scores(seq.groundtruth, run.trajectory)
            rows[name]["ms_per_frame"] = run.ms_per_frame
            if out:
                write_trajectory(out / f"{name}.txt", run.trajectory)
        stop()

    if out:
        _write_outputs(out, seq, ours.res, cfg)
    if args.json:
        print(json.dumps({"scenario": args.scenario, "frames": len(seq), "seed": args.seed,
                          "skipped": ours.skipped, "dropped": len(ours.res.dropped),
                          "segmentation": ours.seg.as_dict(), "methods": rows}, indent=1))
        return 0
    _print_table(rows, ours, out)
    return 0


class _Ours(NamedTuple):
    """jaxvo's run on the demo scene and its scores."""

    res: Any  # SequenceResult
    row: dict  # trajectory scores, F-measure, steady ms/frame
    seg: Any  # SegmentationScores at the grid
    skipped: int  # frame pairs skipped
    scan_steady: float  # seconds of a second, compiled run of the scan


def _run_jaxvo(seq, cfg, seed: int, progress) -> _Ours:
    """jaxvo on the scene, scored; its speed is the host flow plus a second, already
    compiled run of the scan (steady state)."""
    from jaxvo.evaluation.scores import segmentation_scores, trajectory_scores
    from jaxvo.odometry import run_sequence
    from jaxvo.status import Status

    res = run_sequence(seq, cfg=cfg, seed=seed, progress=progress)
    row = trajectory_scores(seq.groundtruth, res.trajectory)
    seg = segmentation_scores(_Anchors(seq, res.frames), res.outputs.moving, cfg.cell)
    row["f_measure"] = seg.f_measure
    scan_steady = _timed_scan(res, cfg, seed)
    row["ms_per_frame"] = 1e3 * (res.flow_seconds + scan_steady) / (len(res.frames) - 1)
    skipped = int((res.outputs.status != Status.OK).sum())
    return _Ours(res, row, seg, skipped, scan_steady)


def _timed_scan(res, cfg, seed: int) -> float:
    """Seconds of a second run of the scan ``run_sequence`` compiled, called as it called
    it (:func:`jaxvo.odometry.scan_flows`), so that nothing compiles: called with other
    argument types it compiled again, and the demo's table timed the compile instead of
    the steady state (docs/report/host_decisions.md)."""
    import time

    import jax

    from jaxvo.odometry import scan_flows

    t0 = time.perf_counter()
    jax.block_until_ready(scan_flows(res.flows, res.keyframes, res.trajectory.poses[0],
                                     cfg=cfg, grid=res.grid, seed=seed))
    return time.perf_counter() - t0


def _write_outputs(out, seq, res, cfg) -> None:
    """The ground truth, jaxvo's trajectory and six overlays into ``out``."""
    import jax

    from jaxvo.host.readers.io import write_trajectory
    from jaxvo.host.writers.masks import overlay_panel
    from jaxvo.host.writers.outputs import write_image

    write_trajectory(out / "groundtruth.txt", seq.groundtruth)
    write_trajectory(out / "jaxvo.txt", res.trajectory)
    n_pairs = len(res.frames) - 1
    for k in range(0, n_pairs, max(1, n_pairs // 6)):
        step_out = jax.tree.map(lambda a, k=k: a[k], res.outputs)
        image = seq[int(res.frames[k])]  # the pair's labels lie on its first image
        write_image(out / f"overlay_{image.timestamp:.6f}.png",
                    overlay_panel(image.bgr, step_out, cfg.cell))


def _print_table(rows: dict, ours: _Ours, out) -> None:
    res, seg = ours.res, ours.seg
    print()
    print(f"  {'method':<13}{'ATE rmse':>10}{'RPE trans':>11}{'RPE rot':>10}{'F-measure':>11}{'ms/frame':>10}")
    print(f"  {'':<13}{'[m]':>10}{'[m/frame]':>11}{'[deg/fr]':>10}{'(grid)':>11}{'':>10}")
    for name, r in rows.items():
        f = f"{r['f_measure']:.3f}" if "f_measure" in r else "-"
        print(f"  {name:<13}{r['ate_rmse_m']:>10.4f}{r['rpe_trans_m_per_frame']:>11.4f}"
              f"{r['rpe_rot_deg_per_frame']:>10.3f}{f:>11}{r['ms_per_frame']:>10.1f}")
    print()
    print(f"  segmentation: recall {seg.recall:.3f}, precision {seg.precision:.3f} "
          f"(moving = positive, {seg.frames} frames, at grid points)")
    print(f"  jaxvo: {ours.skipped} of {len(res.frames) - 1} frame pairs skipped, "
          f"{len(res.dropped)} frames dropped; flow {res.flow_seconds:.2f} s on the host, scan "
          f"{ours.scan_steady:.2f} s ({res.scan_seconds:.1f} s on the first call, compile "
          "included); ms/frame are steady state")
    if out:
        print(f"  trajectories and overlays written to {out}")
