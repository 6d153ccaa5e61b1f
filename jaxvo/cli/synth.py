"""``jaxvo synth``: write a synthetic (or composited) dynamic RGB-D sequence to disk."""

from __future__ import annotations

import argparse
import sys
import time

# Kept in step with jaxvo.synth.scenes.SCENARIOS (checked by the tests); listed here so that
# ``--help`` does not import JAX.
SCENARIO_NAMES = ("fixed_camera_1", "fixed_camera_2", "handheld_fast", "handheld_slow",
                  "close_approach", "static", "three_boxes", "enter_leave", "stop_start",
                  "heavy_cover_50", "heavy_cover_70", "heavy_cover_90", "carried_50",
                  "carried_70")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Render a seeded synthetic RGB-D sequence with exact ground truth (camera and object "
        "trajectories, per-pixel object masks) in the TUM layout, or insert the moving "
        "objects of a scenario into a real sequence with --composite."
    )
    parser.add_argument("scenario", metavar="SCENARIO",
                        help=f"scenario preset: {', '.join(SCENARIO_NAMES)}")
    parser.add_argument("out_dir", metavar="OUT_DIR",
                        help="folder to write (created; an existing one must be empty)")
    parser.add_argument("--frames", type=int, default=None,
                        help="number of frames (default 90; with --composite all frames)")
    parser.add_argument("--seed", type=int, default=0, help="seed, 0 .. 2**32-1 (default 0)")
    parser.add_argument("--composite", metavar="SEQ_DIR", default=None,
                        help="real TUM-layout sequence with groundtruth.txt and camera.txt "
                        "to insert the scenario's objects into")
    parser.add_argument("--ideal", action="store_true",
                        help="no sensor noise, no depth holes, no range limit")
    parser.add_argument("--motion-blur", action="store_true", help="blur the colour images")
    parser.add_argument("--exposure-change", action="store_true",
                        help="let the colour gain drift like auto exposure")


def check_scenario(name: str) -> None:
    """Refuse a scenario no preset has, before NumPy loads, in the words
    :mod:`jaxvo.synth.scenes` says it (``jaxvo demo --scenario`` takes the same names)."""
    from jaxvo.errors import InputError

    if name not in SCENARIO_NAMES:
        raise InputError(f"unknown scenario {name!r}; choose one of {', '.join(SCENARIO_NAMES)}")


def _check(args: argparse.Namespace) -> None:
    """What needs neither NumPy nor a file read: the seed, the frame count, the scenario's
    name and a composite's sequence being there."""
    from jaxvo.cli.inputs import require_sequence
    from jaxvo.errors import InputError, check_seed

    check_seed(args.seed, name="--seed")
    if args.frames is not None and args.frames < 1:
        raise InputError(f"--frames must be at least 1, got {args.frames}")
    check_scenario(args.scenario)
    if args.composite:
        require_sequence(args.composite)


def prepare(args: argparse.Namespace):
    """The options checked, a composite's sequence opened and the (empty) output folder
    made, before JAX loads: ``(opts, real, frames)`` for :func:`run`. :func:`_check`'s
    answers come before NumPy loads, and so does an OUT_DIR that is a file or not empty
    where there is no composite: said before the memory is checked (with two things
    wrong, OUT_DIR first). With a composite, OUT_DIR may hold what it reads, said as such
    once the sequence is opened, as before."""
    _check(args)
    from jaxvo.host.writers.outputs import check_outputs, folder_target, output_folder

    if not args.composite:
        folder_target(args.out_dir, what="OUT_DIR", empty=True)
    from dataclasses import replace
    from pathlib import Path

    from jaxvo.config import Config
    from jaxvo.host.services.memory import (
        SYNTH_BYTES_PER_FRAME,
        SYNTH_BYTES_PER_OBJECT_FRAME,
        check_memory,
        run_bytes,
    )
    from jaxvo.synth import scenes as synth

    opts = synth.SensorOptions.ideal() if args.ideal else synth.SensorOptions()
    opts = replace(opts, motion_blur=args.motion_blur,
                         exposure_change=args.exposure_change)
    reads, real = [], None
    if args.composite:
        from jaxvo.host.readers.io import open_sequence

        real = open_sequence(args.composite)
        frames = len(real) if args.frames is None else min(args.frames, len(real))
        reads = real.files(frames)
    else:
        frames = synth.DEFAULT_FRAMES if args.frames is None else args.frames
    objects = len(synth.SCENARIOS[args.scenario].objects)
    # frames are rendered and written one at a time; their trajectories are held whole
    check_memory(run_bytes(Config(), height=480, width=640, host_bytes=frames * (
        SYNTH_BYTES_PER_FRAME + SYNTH_BYTES_PER_OBJECT_FRAME * objects)),
        what=f"jaxvo synth --frames {frames}")
    # before any frame is rendered: a folder of its own, never one holding what it reads
    check_outputs(reads, folders={"OUT_DIR": Path(args.out_dir)})
    output_folder(args.out_dir, what="OUT_DIR", empty=True)
    return opts, real, frames


def run(args: argparse.Namespace, prepared=None) -> int:
    from jaxvo.cli.main import interrupt_at_safe_points
    from jaxvo.synth import scenes as synth

    opts, real, frames = prepared or prepare(args)
    start = time.perf_counter()
    if args.composite:
        seq = synth.composite_sequence(real, args.scenario, frames=args.frames,
                                       seed=args.seed, options=opts)
    else:
        seq = synth.make_sequence(args.scenario, frames=frames, seed=args.seed, options=opts)
    tty = sys.stderr.isatty()

    with interrupt_at_safe_points() as stop:

        def progress(done: int, total: int) -> None:
            stop()  # between frames: never inside the renderer's compile
            if tty or done == total:
                end = "\n" if done == total else ""
                print(f"\rsynth: {seq.name}: frame {done}/{total}", end=end, file=sys.stderr,
                      flush=True)

        out = synth.write_sequence(seq, args.out_dir, progress=progress)
    took = time.perf_counter() - start
    k = len(seq.object_trajectories)
    print(f"wrote {len(seq)} frames ({seq.width}x{seq.height}, {k} moving "
          f"object{'' if k == 1 else 's'}) to {out} in {took:.1f} s")
    return 0
