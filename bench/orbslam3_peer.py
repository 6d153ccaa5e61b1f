"""ORB-SLAM3 (RGB-D) as a peer, run in its own process, alone or with dynamic pixels masked.

``pyorbslam3`` (ORB-SLAM3's Python bindings, ``pip install pyorbslam3``) is GPL-3.0: the
jaxvo package never imports it, and neither does the process that imports this module.
:class:`OrbSlam3` starts a child process (this file with ``--serve``) that imports it and
tracks the frames sent to it over a pipe, one at a time, as a live camera would give them;
at the end it shuts ORB-SLAM3 down and sends back the end-of-run trajectory (ORB-SLAM3's
``SaveTrajectoryTUM`` after its final optimisation: every frame tracked, none of the frames
before initialisation or while lost) and the milliseconds each ``track_rgbd`` call took.

Masking (thesis Fig. 5.8, the segmentation as a plug-in for another odometry): ORB-SLAM3
takes no pixel mask, so the dynamic pixels are removed from its input: their depth is set
to 0 (no RGB-D point is made there), and with ``Masking.image`` their colour too (no ORB
feature is found there), after growing the mask by ``Masking.grow`` pixels.

The vocabulary: ``$PYORBSLAM3_VOCAB`` (pyorbslam3's own setting) when set, else
``orbslam3/ORBvoc.txt`` beside the shared data folder (``$JAXVO_DATA/../orbslam3``), the
stand-in vocabulary trained on the shared frames (its README says how; the official file
is not reachable from these machines). The reports name the file they used.

Command line (a TUM-layout folder in, a TUM trajectory out)::

    python bench/orbslam3_peer.py SEQ_DIR --out traj.txt [--masks DIR] [--image] [--grow K]

``--masks`` reads one PNG per frame named by its timestamp as ``jaxvo run --dynamic-masks``
writes them (255 = dynamic).
"""

from __future__ import annotations

import argparse
import functools
import os
import pickle
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

NAME = "orbslam3"


# ------------------------------------------------------------------ vocabulary, settings


def vocabulary() -> Path:
    """The ORB vocabulary file: ``$PYORBSLAM3_VOCAB``, else the shared stand-in."""
    env = os.environ.get("PYORBSLAM3_VOCAB")
    if env:
        return Path(env)
    from jaxvo.host.readers.io import data_root

    return data_root().parent / "orbslam3" / "ORBvoc.txt"


def vocabulary_note(path: Path | None = None) -> str:
    """One sentence for the reports: which vocabulary the ORB-SLAM3 figures used."""
    path = vocabulary() if path is None else Path(path)
    readme = path.parent / "README.md"
    if readme.is_file() and "stand-in" in readme.read_text():
        return (f"ORB-SLAM3 ran with the stand-in ORB vocabulary `{path.name}` (trained on "
                "the shared frames, see the README beside it), not the official ORBvoc.txt: "
                "frame-to-frame tracking barely depends on it, relocalisation and loop "
                "closing may differ.")
    return f"ORB-SLAM3 ran with the ORB vocabulary `{path.name}`."


@functools.cache
def missing() -> str | None:
    """None when ORB-SLAM3 can run here, else one line saying why not. The import is
    tried in a child interpreter, so this process never loads pyorbslam3."""
    r = subprocess.run([sys.executable, "-c", "import pyorbslam3"], check=False, capture_output=True,
                       text=True)
    if r.returncode:
        last = (r.stderr.strip().splitlines() or ["import failed"])[-1]
        if "No module named 'pyorbslam3'" in last:
            return "pyorbslam3 is not installed (pip install pyorbslam3)"
        return (f"pyorbslam3 does not load ({last}); it needs the OpenGL/X11 runtime "
                "libraries: apt-get install libgl1 libegl1 libopengl0 libsm6 libice6 "
                "libx11-6 libxext6")
    path = vocabulary()
    if not path.is_file():
        return (f"no ORB vocabulary at {path} (set PYORBSLAM3_VOCAB, or JAXVO_DATA to the "
                "shared data folder with orbslam3/ beside it)")
    return None


def settings_yaml(K, width: int, height: int, *, fps: float = 30.0, features: int = 1000) -> str:
    """ORB-SLAM3's RGB-D settings (file format 1.0) for an undistorted pinhole camera whose
    depth is sent in metres (``RGBD.DepthMapFactor`` 1) and colour in BGR order.

    Args:
      K: :class:`jaxvo.host.frontend.camera.Intrinsics` (fx, fy, cx, cy in pixels).
      width, height: image size, pixels.
      fps: frame rate, Hz (ORB-SLAM3 reads an integer).
      features: ORB features per image (ORB-SLAM3's TUM settings use 1000).
    Returns:
      the YAML text.
    """
    # Stereo.b and ThDepth: points nearer than ThDepth * b (3.2 m) are "close" (one view
    # gives them depth); the values are those of ORB-SLAM3's TUM RGB-D settings.
    return f"""%YAML:1.0
File.version: "1.0"
Camera.type: "PinHole"
Camera1.fx: {float(K.fx):.6f}
Camera1.fy: {float(K.fy):.6f}
Camera1.cx: {float(K.cx):.6f}
Camera1.cy: {float(K.cy):.6f}
Camera.width: {int(width)}
Camera.height: {int(height)}
Camera.fps: {round(fps)}
Camera.RGB: 0
Stereo.ThDepth: 40.0
Stereo.b: 0.08
RGBD.DepthMapFactor: 1.0
ORBextractor.nFeatures: {int(features)}
ORBextractor.scaleFactor: 1.2
ORBextractor.nLevels: 8
ORBextractor.iniThFAST: 20
ORBextractor.minThFAST: 7
Viewer.KeyFrameSize: 0.05
Viewer.KeyFrameLineWidth: 1.0
Viewer.GraphLineWidth: 0.9
Viewer.PointSize: 2.0
Viewer.CameraSize: 0.08
Viewer.CameraLineWidth: 3.0
Viewer.ViewpointX: 0.0
Viewer.ViewpointY: -0.7
Viewer.ViewpointZ: -1.8
Viewer.ViewpointF: 500.0
"""


# --------------------------------------------------------------------------------- masks


class Masking(NamedTuple):
    """How dynamic pixels are taken out of ORB-SLAM3's input."""

    image: bool = False  # also black out the colour (else only the depth is set to 0)
    grow: int = 0  # pixels by which the mask is dilated first

    @property
    def name(self) -> str:
        return ("depth+image" if self.image else "depth") + (f", grown {self.grow} px"
                                                            if self.grow else "")


# The variants compared on the development split (bench/bench_orbslam3.py) and on the TUM
# walking clip (bench/orbslam3_clip_masking.py), and the one chosen: the depth of the
# dynamic pixels set to 0, not grown (what `jaxvo run --dynamic-masks` writes). On the clip
# (real people, what the plug-in is for) it ties for the lowest median, 11.0 mm [9.6-17.2]
# from the people-masked reference over 6 runs, against 12.5 [11.9-21.7] for colour too and
# 8 px of growth, which the dev split's rule had put first (geometric mean of ATE masked /
# alone 0.260 against 0.270, within ORB-SLAM3's spread, on composites of boxes);
# docs/report/orbslam3_clip_masking.md, orbslam3_dev.md.
VARIANTS = (Masking(False, 0), Masking(True, 0), Masking(False, 8), Masking(True, 8),
            Masking(True, 16))
CHOSEN = Masking(False, 0)


def mask_frame(bgr: np.ndarray, depth: np.ndarray, mask: np.ndarray | None,
               masking: Masking = CHOSEN) -> tuple[np.ndarray, np.ndarray]:
    """The frame with the ``mask`` pixels taken out as ``masking`` says.

    Args:
      bgr: (H, W, 3) uint8.
      depth: (H, W) float metres, 0 = no reading.
      mask: (H, W) bool, True = dynamic (remove); None = leave the frame as it is.
    Returns:
      ``(bgr, depth)``: new arrays where changed (the inputs are not written to); the
      depth float32.
    """
    depth = np.asarray(depth, np.float32)
    if mask is None or not mask.any():
        return bgr, depth
    mask = np.asarray(mask, bool)
    if masking.grow > 0:
        g = masking.grow
        mask = cv2.dilate(mask.astype(np.uint8), np.ones((2 * g + 1, 2 * g + 1), np.uint8)) > 0
    depth = np.where(mask, np.float32(0), depth)
    if masking.image:
        bgr = np.where(mask[..., None], np.uint8(0), bgr)
    return bgr, depth


# --------------------------------------------------------------------- the child process


def _serve(vocab: str, settings: str, log: str) -> None:
    """The child (``orbslam3_peer.py --serve``): ORB-SLAM3 over the frames pickled on its
    standard input until None arrives; the run goes back pickled on its standard output."""
    out = os.fdopen(os.dup(1), "wb")
    inp = sys.stdin.buffer
    # ORB-SLAM3 prints to the C streams: into the log file, off the parent's pipe
    fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    try:
        import pyorbslam3

        t0 = time.perf_counter()
        slam = pyorbslam3.Slam(vocab, settings, pyorbslam3.Sensor.RGBD, use_viewer=False)
        load_s = time.perf_counter() - t0
        ms, states = [], []
        while (msg := pickle.load(inp)) is not None:
            bgr, depth, t = msg
            t0 = time.perf_counter()
            r = slam.track_rgbd(bgr, depth, t)
            ms.append(1e3 * (time.perf_counter() - t0))
            states.append(r.state.name)
        slam.shutdown()
        path = settings + ".traj.txt"
        slam.save_trajectory_tum(path)
        rows = np.loadtxt(path, ndmin=2) if os.path.getsize(path) else np.zeros((0, 8))
        reply = ("ok", rows, ms, states, load_s)
    except Exception as exc:  # noqa: BLE001 - every failure goes back as one line
        reply = ("error", f"{type(exc).__name__}: {exc}", None, None, None)
    pickle.dump(reply, out)
    out.flush()


class OrbRun(NamedTuple):
    """What an ORB-SLAM3 run gives back."""

    trajectory: object  # jaxvo.trajectory.Trajectory of the frames tracked (camera-to-world)
    ms: np.ndarray  # (frames,) milliseconds of each track_rgbd call
    states: list[str]  # (frames,) ORB-SLAM3's tracking state after each frame
    load_s: float  # seconds to load the vocabulary and start the system

    @property
    def ms_per_frame(self) -> float:
        """Median milliseconds per frame, the first frame (initialisation) left out."""
        return float(np.median(self.ms[1:])) if len(self.ms) > 1 else float("nan")

    @property
    def lost(self) -> int:
        """Frames after the first whose state is not OK (not initialised, lost)."""
        return sum(s != "OK" for s in self.states[1:])


class OrbSlam3:
    """ORB-SLAM3 RGB-D in a child process (this file run with ``--serve``), fed frame by
    frame over a pipe.

    Example::

        orb = OrbSlam3(seq.intrinsics, seq.width, seq.height)
        for f in seq:
            orb.track(f.bgr, f.depth, f.timestamp)   # depth float metres
        run = orb.finish()   # OrbRun: end-of-run trajectory, ms per frame

    Args:
      intrinsics: :class:`jaxvo.host.frontend.camera.Intrinsics` of the depth-registered camera.
      width, height: image size, pixels.
      vocab: ORB vocabulary file (default :func:`vocabulary`).
    """

    def __init__(self, intrinsics, width: int, height: int, *, vocab=None):
        self._dir = tempfile.TemporaryDirectory(prefix="orbslam3_")
        settings = Path(self._dir.name) / "settings.yaml"
        settings.write_text(settings_yaml(intrinsics, width, height))
        self.log = Path(self._dir.name) / "orbslam3.log"
        self._proc = subprocess.Popen(
            [sys.executable, __file__, "--serve", str(vocab or vocabulary()), str(settings),
             str(self.log)], stdin=subprocess.PIPE, stdout=subprocess.PIPE)

    def _failed(self, why: str):
        tail = (self.log.read_text(errors="replace").strip().splitlines()[-5:]
                if self.log.is_file() else [])
        self._proc.kill()
        self._proc.wait()
        self._dir.cleanup()
        return RuntimeError("ORB-SLAM3: " + "; ".join([why, *tail]))

    def track(self, bgr: np.ndarray, depth: np.ndarray, timestamp: float) -> None:
        """Send one frame: (H, W, 3) uint8 BGR, (H, W) float metres (0 = none), seconds."""
        try:
            pickle.dump((np.ascontiguousarray(bgr), np.ascontiguousarray(depth, np.float32),
                         float(timestamp)), self._proc.stdin, protocol=5)
        except BrokenPipeError:
            raise self._failed(f"the process ended (exit code {self._proc.wait()})") from None

    def finish(self) -> OrbRun:
        """Shut ORB-SLAM3 down and return the run (after its final optimisation).

        Raises:
          RuntimeError: the child failed; the message carries its last log lines.
        """
        from jaxvo.trajectory import Trajectory
        from jaxvo.transforms import pose_from_tq

        try:
            pickle.dump(None, self._proc.stdin)
            self._proc.stdin.close()
            status, rows, ms, states, load_s = pickle.load(self._proc.stdout)
        except (EOFError, BrokenPipeError):
            raise self._failed(f"the process ended (exit code {self._proc.wait()})") from None
        if status != "ok":
            raise self._failed(rows)
        self._proc.wait()
        self._dir.cleanup()
        poses = np.array([pose_from_tq(r[1:4], r[4:8]) for r in rows]).reshape(-1, 4, 4)
        traj = Trajectory(rows[:, 0].astype(np.float64), poses)
        return OrbRun(traj, np.asarray(ms), states, load_s)


# ---------------------------------------------------------------- sequences, jaxvo masks


def anchored(traj, gt):
    """``traj`` moved so that its first pose is the ground-truth pose at that time (the
    peers' convention: estimate and truth share a frame), or left as it is without one."""
    from jaxvo.trajectory import Trajectory, pose_at

    if gt is None or not len(traj):
        return traj
    T = pose_at(gt, float(traj.timestamps[0]))
    if T is None:
        return traj
    return Trajectory(traj.timestamps, T @ np.linalg.inv(traj.poses[0]) @ traj.poses)


def run_orbslam3(seq, *, keep: Callable[[int], np.ndarray] | None = None,
                 masking: Masking = CHOSEN):
    """ORB-SLAM3 over ``seq``, as :func:`jaxvo.host.services.peers.run_peer` runs a peer.

    Args:
      seq: a sequence (``len``, ``seq[i] -> Frame``, ``intrinsics``, ``width``,
        ``height``, optional ``groundtruth``).
      keep: optional ``index -> (H, W) bool`` pixels ORB-SLAM3 may use; the others are
        taken out as ``masking`` says.
      masking: how.
    Returns:
      ``(PeerRun, OrbRun)``: the peer's trajectory (anchored at the ground truth),
      frames not tracked and median ms per frame, and the whole run.
    """
    from jaxvo.host.services.peers import PeerRun

    orb = OrbSlam3(seq.intrinsics, seq.width, seq.height)
    for i in range(len(seq)):
        f = seq[i]
        orb.track(*mask_frame(f.bgr, f.depth, None if keep is None else ~keep(i), masking),
                  f.timestamp)
    run = orb.finish()
    traj = anchored(run.trajectory, getattr(seq, "groundtruth", None))
    return PeerRun(traj, run.lost, run.ms_per_frame), run


def all_peers() -> list[str]:
    """Every peer that can run here: :func:`jaxvo.host.services.peers.available_peers`, then ORB-SLAM3
    where :func:`missing` finds nothing missing."""
    from jaxvo.host.services.peers import available_peers

    return available_peers() + ([] if missing() else [NAME])


def run_any_peer(seq, kind: str, *, keep: Callable[[int], np.ndarray] | None = None):
    """:func:`jaxvo.host.services.peers.run_peer` for the peers of the package, :func:`run_orbslam3`
    for ORB-SLAM3: a :class:`jaxvo.host.services.peers.PeerRun` either way."""
    from jaxvo.host.services.peers import run_peer

    return run_orbslam3(seq, keep=keep)[0] if kind == NAME else run_peer(seq, kind, keep=keep)


def streaming_masks(seq, odo, *, grow: int = 0) -> Iterator[tuple[object, np.ndarray]]:
    """jaxvo's dynamic pixels of each frame, frame by frame as a robot gets them.

    ``odo.process`` of frame ``k + 1`` labels the grid of image ``k`` (the previous image
    of the pair, where its flow was measured: ``jaxvo.host.writers.plugin``), so each frame comes out
    one frame late with its mask (``StepOutput.dynamic``: moving cells and their unmeasured
    neighbours, as pixels); the last frame takes the last mask, as ``jaxvo run
    --dynamic-masks`` gives it. A frame jaxvo dropped takes the mask before it.

    Args:
      seq: frames in order (each with ``bgr``, ``depth``, ``timestamp``).
      odo: a fresh :class:`jaxvo.Odometry`.
      grow: grid cells by which each dynamic cell is grown (``jaxvo.host.writers.masks.dynamic_pixels``).
    Yields:
      ``(frame, (H, W) bool mask)``, True = dynamic, in frame order.
    """
    from jaxvo.host.writers.masks import dynamic_pixels

    prev, mask = None, None
    for frame in seq:
        r = odo.process(frame.bgr, frame.depth, frame.timestamp)
        h, w = frame.depth.shape
        if mask is None:
            mask = np.zeros((h, w), bool)
        if r.output is not None:
            mask = dynamic_pixels(r.output.dynamic, h, w, odo.cfg.cell, grow=grow)
        if prev is not None:
            yield prev, mask
        prev = frame
    if prev is not None:
        yield prev, mask


def streaming_keep(seq, odo):
    """``keep(i)`` for :func:`run_orbslam3` and :func:`jaxvo.host.services.peers.run_peer` that runs
    jaxvo frame by frame as the peer asks for each frame: jaxvo and the peer in one loop,
    as on a robot, each frame reaching the peer one frame late with its mask
    (:func:`streaming_masks`). Frames must be asked for in order, once each."""
    stream = enumerate(streaming_masks(seq, odo))

    def keep(i: int) -> np.ndarray:
        k, (_, mask) = next(stream)
        if k != i:
            raise ValueError(f"frames are streamed in order: frame {k} is next, not {i}")
        return ~mask

    return keep


# ------------------------------------------------------------------------ command line


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--serve"]:
        _serve(*argv[1:4])
        return 0
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sequence", help="TUM-layout folder (rgb.txt / depth.txt / associations)")
    ap.add_argument("--out", required=True, help="TUM trajectory file to write")
    ap.add_argument("--masks", help="folder of dynamic-pixel PNGs named TIMESTAMP.png "
                    "(jaxvo run --dynamic-masks), 255 = dynamic")
    ap.add_argument("--image", action="store_true", help="black out masked colour too")
    ap.add_argument("--grow", type=int, default=0, help="pixels to grow the masks by")
    args = ap.parse_args(argv)
    why = missing()
    if why:
        print(f"orbslam3_peer: {why}", file=sys.stderr)
        return 2
    from jaxvo.host.readers.io import open_sequence, write_trajectory

    seq = open_sequence(args.sequence)
    keep = None
    if args.masks:
        def keep(i):
            png = Path(args.masks) / f"{seq[i].timestamp:.6f}.png"
            m = cv2.imread(str(png), cv2.IMREAD_GRAYSCALE)
            return np.ones((seq.height, seq.width), bool) if m is None else m < 128
    peer, run = run_orbslam3(seq, keep=keep, masking=Masking(args.image, args.grow))
    write_trajectory(args.out, peer.trajectory, comment=f"ORB-SLAM3 RGB-D {args.sequence}")
    print(f"{len(peer.trajectory)} of {len(seq)} frames tracked, {peer.ms_per_frame:.1f} ms "
          f"per frame (median), vocabulary load {run.load_s:.1f} s; {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
