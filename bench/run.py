"""jaxvo against its peers on the same sequences, in one run: accuracy, segmentation, speed.

Runs jaxvo and every available peer odometry (OpenCV ``cv2.Odometry`` RGB, DEPTH, RGB_DEPTH;
Open3D colour / hybrid when ``open3d`` imports; ORB-SLAM3 in its own process when
``pyorbslam3`` loads, ``bench/orbslam3_peer.py``) on every synthetic scenario, the real
sequences of the data root (7-Scenes also at every 4th frame: fast motion with ground truth)
and a 7-Scenes composite with moving boxes; then each peer again
with jaxvo's dynamic pixels masked out (thesis Fig. 5.8, "Proposed x DVO"). Writes
``report.md`` (Markdown tables), PNG figures and ``results.json`` under ``--out``.

Run: ``.venv/bin/python bench/run.py [--quick] [--frames N] [--out results/]``
"""

from __future__ import annotations

import argparse
import datetime
import functools
import json
import sys
import time
from pathlib import Path

import cv2
import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import orbslam3_peer
from _common import (
    SEVEN_SCENES,
    TUM_WALKING,
    CachedSequence,
    load_average,
    log,
    machine,
    markdown_table,
    peak_rss_mib,
)

from jaxvo.config import Config, Params, grid_shape, params_as_arrays
from jaxvo.core.inputs import stack_flows
from jaxvo.core.pipeline import (
    StepOutput,
    committed_poses,
    final_moving,
    frame_key,
    init_pipeline,
    jit_step,
    run_scan,
)
from jaxvo.core.spatial import segment
from jaxvo.evaluation.metrics import SegmentationScores, ate
from jaxvo.evaluation.scores import segmentation_scores, trajectory_scores
from jaxvo.host.frontend.flow import GridFlowTracker
from jaxvo.host.readers.io import data_root, first_pose, open_sequence, write_trajectory
from jaxvo.host.services.peers import OPEN3D_PEERS
from jaxvo.host.writers.masks import overlay_panel
from jaxvo.host.writers.plugin import dynamic_masks
from jaxvo.status import Status
from jaxvo.synth.scenes import SCENARIOS, composite_sequence, make_sequence
from jaxvo.trajectory import Trajectory

JAXVO = "jaxvo"


# ----------------------------------------------------------------------------- sequences


def build_sequences(frames: int, seed: int, only=None):
    """``[(label, kind, CachedSequence)]`` and ``{label: reason}`` for the skipped ones."""
    seqs, skipped = [], {}
    want = (lambda name: True) if not only else (lambda name: name in only)
    for name in filter(want, SCENARIOS):
        log(f"rendering {name} ({frames} frames)")
        seqs.append((name, "synthetic", CachedSequence(make_sequence(name, frames=frames,
                                                                     seed=seed))))
    # sequences made from the real data: (label, source folder, kind, how to build it)
    real = [
        (SEVEN_SCENES, SEVEN_SCENES, "real, static scene",
         lambda path: CachedSequence(open_sequence(path), frames)),
        (TUM_WALKING, TUM_WALKING, "real, two people walking",
         lambda path: CachedSequence(open_sequence(path), frames)),
        # the same real frames with four times the motion
        (f"{SEVEN_SCENES}_every4", SEVEN_SCENES, "real, static scene, every 4th frame (fast motion)",
         lambda path: CachedSequence(open_sequence(path), frames, step=4)),
        (f"composite_{SEVEN_SCENES}", SEVEN_SCENES, "real + synthetic moving boxes",
         lambda path: CachedSequence(composite_sequence(path, "handheld_slow", frames=frames,
                                                        seed=seed))),
    ]
    for label, source, kind, build in real:
        if not want(label):
            continue
        path = data_root() / source
        if not path.is_dir():
            skipped[label] = f"{source} not found at {path} (set JAXVO_DATA to the shared data folder)"
            continue
        log(f"reading {label}")
        seqs.append((label, kind, build(path)))
    return seqs, skipped


# --------------------------------------------------------------------------------- jaxvo


@functools.cache
def stage_functions(cfg: Config, grid: tuple[int, int]):
    """The spatial stage jitted alone, and the whole per-frame step (spatial, temporal,
    ego-motion), so that the temporal and ego-motion stages' time is their difference."""
    spatial = jax.jit(functools.partial(segment, cfg=cfg, grid=grid))
    step = functools.partial(jit_step, cfg=cfg.step, grid=grid)
    return spatial, step


_COMPILED: dict = {}  # (what, shapes) -> (compiled callable, compile seconds)


def compiled(name: str, shape_key, fn, *args, **static):
    """``fn.lower(*args, **static).compile()``, timed and cached per shape."""
    key = (name, shape_key)
    fresh = key not in _COMPILED
    if fresh:
        t0 = time.perf_counter()
        _COMPILED[key] = (fn.lower(*args, **static).compile(), time.perf_counter() - t0)
    exe, seconds = _COMPILED[key]
    return exe, (seconds if fresh else 0.0)


def host_flows(seq: CachedSequence, cfg: Config):
    """Grid flow of every pair (as ``flows_for_sequence``), each pair timed: (flows, seconds)."""
    tracker = GridFlowTracker(seq.intrinsics, cfg, height=seq.height, width=seq.width)
    flows, times = [], []
    for i, frame in enumerate(seq):
        t0 = time.perf_counter()
        flow = tracker.push(frame.bgr, frame.depth)
        if i:
            times.append(time.perf_counter() - t0)
            flows.append(flow)
    return stack_flows(flows), np.asarray(times)


def time_stages(flows, key, params, cfg: Config, grid):
    """Median ms per frame pair of the spatial stage alone and of the whole per-frame step
    (``jit_step``), run frame by frame on the sequence's precomputed flows (steady state;
    compile timed apart). The temporal and ego-motion stages need the step's state (the
    calibrated noise, the evidence), so they are timed together as the difference."""
    spatial, step = stage_functions(cfg, grid)
    T = len(flows.valid)
    pairs = [jax.tree.map(lambda a, k=k: jnp.asarray(a[k]), flows) for k in range(T)]
    valid = [p.valid & (p.status == Status.OK) for p in pairs]
    keys = [frame_key(key, k) for k in range(T)]
    jax.block_until_ready((pairs, valid, keys))

    compile_s = {}
    sp, compile_s["spatial"] = compiled("spatial", grid, spatial, keys[0], pairs[0].pts_prev,
                                        pairs[0].pts_cur, valid[0], params,
                                        focal=pairs[0].focal)
    t_sp = []
    for k in range(T):
        t0 = time.perf_counter()
        jax.block_until_ready(sp(keys[k], pairs[k].pts_prev, pairs[k].pts_cur, valid[k], params,
                                 focal=pairs[k].focal))
        t_sp.append(time.perf_counter() - t0)

    state = init_pipeline(cfg=cfg.step, grid=grid, params=params)
    t0 = time.perf_counter()
    state, _ = jax.block_until_ready(step(state, pairs[0], key, params))
    compile_s["step"] = time.perf_counter() - t0
    t_st = []
    for k in range(1, T):
        t0 = time.perf_counter()
        state, _ = jax.block_until_ready(step(state, pairs[k], key, params))
        t_st.append(time.perf_counter() - t0)
    ms = {"spatial": 1e3 * float(np.median(t_sp)), "step": 1e3 * float(np.median(t_st))}
    ms["temporal_ego"] = ms["step"] - ms["spatial"]
    return ms, compile_s


def run_jaxvo(seq: CachedSequence, cfg: Config, seed: int, repeats: int):
    """Flow on the host, then the whole-sequence scan (compile apart, median of ``repeats``)."""
    grid = grid_shape(seq.height, seq.width, cfg.cell)
    T0 = first_pose(seq)
    flows, flow_times = host_flows(seq, cfg)
    T = len(flows.valid)
    flows_dev = jax.tree.map(jnp.asarray, flows)
    key = jax.random.key(seed)
    params = params_as_arrays(Params())
    T0j = jnp.asarray(T0, jnp.float32)
    scan, scan_compile = compiled("scan", (T, grid), run_scan, flows_dev, key, params, T0j,
                                  cfg=cfg.step, grid=grid)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        final, outs = jax.block_until_ready(scan(flows_dev, key, params, T0j))
        times.append(time.perf_counter() - t0)
    outs = jax.tree.map(np.asarray, outs)  # StepOutput.noise is itself a NamedTuple
    final_ids = np.asarray(final_moving(final, params))
    rss_after_scan = peak_rss_mib()
    stage_ms, stage_compile = time_stages(flows_dev, key, params, cfg, grid)
    committed = committed_poses(outs)
    poses = np.concatenate([np.asarray(T0, np.float64)[None], np.asarray(committed, np.float64)])
    timing = {
        "flow_ms": 1e3 * float(np.median(flow_times)),
        **{f"{k}_ms": v for k, v in stage_ms.items()},
        "scan_ms": 1e3 * float(np.median(times)) / T,
        "scan_compile_s": scan_compile,
        "stage_compile_s": stage_compile,
        "peak_rss_mib_after_scan": rss_after_scan,
    }
    timing["total_ms"] = timing["flow_ms"] + timing["scan_ms"]
    return Trajectory(seq.timestamps, poses), outs, final_ids, timing


# ------------------------------------------------------------------------------- scoring


def scores(seq: CachedSequence, traj: Trajectory) -> dict | None:
    return trajectory_scores(seq.groundtruth, traj) if seq.groundtruth is not None else None


def pixel_scores(seq: CachedSequence, masks: np.ndarray) -> dict:
    """Pixel-level recall / precision / F of the plug-in masks against the true object masks."""
    s = SegmentationScores()
    for k in range(len(seq)):
        s.add(masks[k].ravel(), (seq[k].mask > 0).ravel())
    return s.as_dict()


def position_errors(seq: CachedSequence, traj: Trajectory):
    """Per-pose ATE (m) over time, aligned as :func:`trajectory_scores` aligns."""
    gt_pos = np.asarray(seq.groundtruth.poses)[:, :3, 3]
    aligned = bool(np.ptp(gt_pos, axis=0).max() > 1e-6)
    a = ate(seq.groundtruth, traj, align=aligned)
    return a.timestamps - seq.timestamps[0], a.errors


# --------------------------------------------------------------------------------- plots


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


_COLOURS = ["tab:blue", "tab:green", "tab:orange", "tab:purple", "tab:brown", "tab:pink"]


def style(name: str) -> dict:
    """jaxvo in red; each peer one colour, solid alone and dashed with jaxvo's mask."""
    if name == JAXVO:
        return {"color": "tab:red", "lw": 1.8}
    base = name.split(" x ")[0]
    peers = orbslam3_peer.all_peers()
    colour = _COLOURS[peers.index(base) % len(_COLOURS)] if base in peers else "grey"
    ls = ":" if name.endswith("true mask") else "--" if " x " in name else "-"
    return {"color": colour, "lw": 1.0, "ls": ls}


def plot_trajectories(path: Path, seq: CachedSequence, trajs: dict, title: str) -> None:
    """Top view (x, z) and x, y, z over time (thesis Figs. 5.3-5.7); ground truth in black."""
    plt = _plt()
    fig = plt.figure(figsize=(11, 5.2))
    gs = fig.add_gridspec(3, 2, width_ratios=(1, 1.4))
    top = fig.add_subplot(gs[:, 0])
    axes = [fig.add_subplot(gs[i, 1]) for i in range(3)]
    t = seq.timestamps - seq.timestamps[0]
    series = []
    if seq.groundtruth is not None:
        g = seq.groundtruth
        series.append(("ground truth", g.timestamps - seq.timestamps[0], g.poses,
                       {"color": "black", "lw": 2.2}))
    for name, traj in trajs.items():
        series.append((name, t, traj.poses, style(name)))
    _xyz_figure(plt, fig, top, axes, series, "top view", title, path)


def _xyz_figure(plt, fig, top, axes, series, top_title: str, title: str, path: Path) -> None:
    """Draw ``(name, t, poses, style)`` series as a top view (x, z) and x, y, z over time."""
    for name, tt, poses, st in series:
        p = np.asarray(poses)[:, :3, 3]
        top.plot(p[:, 0], p[:, 2], label=name, **st)
        for i, ax in enumerate(axes):
            ax.plot(tt, p[:, i], **st)
    top.set_xlabel("x [m]")
    top.set_ylabel("z [m]")
    top.set_title(top_title)
    top.axis("equal")
    top.legend(fontsize=7)
    for i, ax in enumerate(axes):
        ax.set_ylabel(f"{'xyz'[i]} [m]")
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def plot_errors(path: Path, seq: CachedSequence, trajs: dict, title: str) -> None:
    """Position error (ATE per pose, m) over time for every method."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 3.2))
    for name, traj in trajs.items():
        tt, err = position_errors(seq, traj)
        ax.plot(tt, err, label=name, **style(name))
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position error [m]")
    ax.legend(fontsize=7, ncol=2)
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def panel_frames(T: int, count: int) -> list[int]:
    """A few pair indices from a quarter of the way in (labels need a few frames to settle)."""
    return sorted({int(np.rint(x)) for x in np.linspace(T / 4, T - 1, count)})


def plot_labels_and_peers(path: Path, seq: CachedSequence, trajs: dict, outs: StepOutput,
                          cell: int, title: str, count: int = 3) -> None:
    """No ground truth: jaxvo's label overlays of a few frames beside every method's path."""
    from jaxvo.host.writers.masks import overlay

    plt = _plt()
    T = len(outs.ids)
    picks = panel_frames(T, count)
    fig = plt.figure(figsize=(13, 5.6))
    gs = fig.add_gridspec(len(picks), 3, width_ratios=(1.5, 1, 1.2))
    for r, k in enumerate(picks):
        ax = fig.add_subplot(gs[r, 0])
        ax.imshow(cv2.cvtColor(overlay(seq[k].bgr, outs.ids[k], cell), cv2.COLOR_BGR2RGB))
        ax.set_title(f"jaxvo labels, frame {k}", fontsize=8)
        ax.axis("off")
    top = fig.add_subplot(gs[:, 1])
    axes = [fig.add_subplot(gs[i * len(picks) // 3, 2]) for i in range(min(3, len(picks)))]
    t = seq.timestamps - seq.timestamps[0]
    series = [(name, t, traj.poses, style(name)) for name, traj in trajs.items()]
    _xyz_figure(plt, fig, top, axes, series, "top view (no ground truth)", title, path)


def stage_panels(path: Path, seq: CachedSequence, outs: StepOutput, cell: int,
                 count: int = 3) -> list[int]:
    """Thesis Fig. 5.1-style panels (Model, Hypotheses, Segments, Group) of a few frames."""
    T = len(outs.ids)
    picks = panel_frames(T, count)
    rows = []
    for k in picks:
        out = jax.tree.map(lambda f, k=k: f[k], outs)
        panel = overlay_panel(seq[k].bgr, out, cell, scale=0.3)
        cv2.putText(panel, f"frame {k}", (6, panel.shape[0] - 8), cv2.FONT_HERSHEY_SIMPLEX,
                    0.45, (255, 255, 255), 1, cv2.LINE_AA)
        rows.append(panel)
    cv2.imwrite(str(path), np.concatenate(rows, axis=0), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    return picks


# -------------------------------------------------------------------------------- report


def fmt(x, digits=4):
    if x is None:
        return "-"
    if isinstance(x, float):
        return f"{x:.{digits}f}" if abs(x) >= 10 ** -digits or x == 0 else f"{x:.2e}"
    return str(x)


def table(header: list[str], rows: list[list], digits=None) -> str:
    """Markdown table; ``digits`` gives the decimals of each column (default 4)."""
    digits = digits or [4] * len(header)
    return markdown_table(header, [[c if isinstance(c, str) else fmt(c, d)
                                    for c, d in zip(r, digits, strict=False)] for r in rows])


def write_report(out: Path, res: dict) -> None:
    m = res["machine"]
    seqs = res["sequences"]
    peers = res["peers"]
    methods = [JAXVO] + peers
    L = [f"# jaxvo benchmark report ({res['mode']} run)", ""]
    L += [(f"Generated {res['started']} by `{res['command']}` in {res['wall_s'] / 60:.1f} min. "
          "Every figure below comes from this run; `results.json` holds them all."), ""]
    L += ["## Machine", "", table(["", ""], [
        ["platform", m["platform"]], ["CPU", m["cpu_model"]], ["cores", str(m["cores"])],
        ["JAX", f"{m['jax']} ({m['jax_backend']}, {', '.join(m['jax_devices'])})"],
        ["OpenCV", m["opencv"]], ["NumPy", m["numpy"]], ["Python", m["python"]],
        ["load average (1, 5, 15 min) at start", str(m["load_average_start"])],
        ["load average at end", str(m["load_average_end"])],
    ]), ""]
    L += [("Other processes share these cores, so timings are noisy: every time is a median "
          "over frames (jaxvo's scan: median of repeated whole-sequence runs, divided by the "
          "pairs)."), ""]
    L += ["## Methods", ""]
    L += [f"- **{JAXVO}**: this package, default `Config` and `Params`, seed {res['seed']}.",
          ("- **opencv_rgb / opencv_depth / opencv_rgbd**: `cv2.Odometry` (RGB, DEPTH, "
          "RGB_DEPTH), frame to frame, default settings."),
          ("- **PEER x jaxvo**: the same peer with jaxvo's dynamic pixels masked out of every "
          "frame (`jaxvo.host.writers.plugin.dynamic_masks`, thesis Fig. 5.8 \"Proposed x DVO\"); image "
          "k takes the labels of pair k -> k+1, the last image the final compensated "
          "temporal map."),
          "- **Open3D** (colour / hybrid RGB-D odometry): " + (
              "installed and included." if res["open3d"] else
              "**not installed in this environment, so absent from this report**; "
              "`pip install open3d` adds `open3d_color` and `open3d_hybrid` to every table."),
          "- **orbslam3**: " + (
              "ORB-SLAM3 RGB-D (`pyorbslam3`, in its own process: `bench/orbslam3_peer.py`), "
              "its end-of-run trajectory (after its final optimisation; frames before "
              "initialisation or while lost left out), ms per `track_rgbd` call; x jaxvo: "
              "jaxvo's dynamic pixels taken out of its input "
              f"(`{orbslam3_peer.CHOSEN.name}`, chosen on the development split by "
              "`bench/bench_orbslam3.py`). It is multi-threaded and "
              "not deterministic: one run each here, the spread in `bench_orbslam3.py`'s "
              f"report. {res['orbslam3']}" if "orbslam3" in res["peers"] else
              f"**skipped**: {res.get('orbslam3', 'not measured in this run')}."),
          ""]
    L += ["## Sequences", ""]
    rows = [[s, d["kind"], str(d["frames"]), f"{d['duration_s']:.2f}",
             f"{d['width']}x{d['height']}", "yes" if d["groundtruth"] else "no",
             "yes" if d["masks"] else "no"] for s, d in seqs.items()]
    L += [table(["sequence", "kind", "frames", "duration [s]", "size", "ground truth",
                 "object masks"], rows), ""]
    for s, why in res["skipped"].items():
        L += [f"- skipped **{s}**: {why}"]
    if res["skipped"]:
        L += [""]

    with_gt = [s for s, d in seqs.items() if d["groundtruth"]]
    all_methods = methods + [f"{p} x jaxvo" for p in peers]

    def acc_table(field, title, unit_note):
        rows = []
        for s in with_gt:
            sc = seqs[s]["scores"]
            rows.append([s] + [sc.get(mm, {}).get(field) if sc.get(mm) else None
                               for mm in all_methods])
        return [f"### {title}", "", unit_note, "", table(["sequence"] + all_methods, rows), ""]

    L += ["## Odometry accuracy (thesis Table 5.4 layout)", ""]
    L += [("RMSE over the sequence. ATE after rigid (no scale) alignment, except for a camera "
          "that never moves (fixed_camera_*), where no alignment is defined and the estimate "
          "(which starts at the true first pose) is compared as it is. Lower is better."), ""]
    L += acc_table("ate_rmse_m", "ATE [m]", "Absolute trajectory error, metres.")
    L += acc_table("rpe_trans_m_per_frame", "RPE translation [m/frame]",
                   "Relative pose error over 1 frame, metres per frame.")
    L += acc_table("rpe_rot_deg_per_frame", "RPE rotation [deg/frame]",
                   "Relative pose error over 1 frame, degrees per frame.")
    L += acc_table("rpe_trans_m_per_s", "RPE translation [m/s]",
                   "Relative pose error over 1 s (sequences longer than 1 s), metres per "
                   "second.")
    L += acc_table("rpe_rot_deg_per_s", "RPE rotation [deg/s]",
                   "Relative pose error over 1 s, degrees per second.")
    rows = [[s] + [str(seqs[s]["failures"].get(mm, "-")) for mm in all_methods] for s in seqs]
    L += ["### Skipped / failed frame pairs", "",
          ("jaxvo: pairs whose status is not OK (pose carried over); peers: pairs where "
          "`compute()` failed (pose carried over)."), "",
          table(["sequence"] + all_methods, rows), ""]

    L += ["## Segmentation (thesis Table 5.3 layout)", ""]
    L += [("jaxvo's moving grid points (`StepOutput.moving`: a moving temporal identifier, or a moving identifier in the pair's matched measurement) against "
          "the true object masks at the cell centres of the image each pair's labels are "
          "anchored on; counted over the whole sequence. *Plug-in mask* scores the pixel "
          "masks handed to the peers (moving cells grown by one cell) against the true "
          "pixel masks."), ""]
    rows = []
    for s, d in seqs.items():
        if d.get("segmentation"):
            g, p = d["segmentation"], d.get("mask_pixels") or {}
            rows.append([s, 100 * g["recall"], 100 * g["precision"], g["f_measure"],
                         100 * p.get("recall", float("nan")),
                         100 * p.get("precision", float("nan")), p.get("f_measure")])
    L += [table(["environment", "recall [%]", "precision [%]", "F-measure",
                 "plug-in mask recall [%]", "plug-in mask precision [%]",
                 "plug-in mask F-measure"], rows, [0, 2, 2, 4, 2, 2, 4]), ""]
    L += [("A sequence with no moving object has no positives: recall is undefined there "
          "(reported as 0) and any moving label is a false positive."), ""]

    L += ["## Speed", ""]
    L += [("jaxvo, milliseconds per frame pair (medians). *flow*: grid flow on the host. "
          "*spatial*: the spatial stage jitted alone, *step*: the whole per-frame step "
          "(`jit_step`), each run frame by frame on the sequence's precomputed flows (steady "
          "state, dispatch included); *temporal + ego*: their difference. "
          "*scan*: the whole-sequence `lax.scan` (all device stages fused), steady state. "
          "*total* = flow + scan. Compile times are apart (0 = already compiled for this "
          "shape earlier in the run). *peak RSS*: `resource.getrusage(RUSAGE_SELF)."
          "ru_maxrss`, the process's high-water mark so far (it includes the cached frames of "
          "every sequence read so far, not jaxvo alone)."), ""]
    rows = []
    for s, d in seqs.items():
        t = d["timing"][JAXVO]
        rows.append([s, t["flow_ms"], t["spatial_ms"], t["temporal_ego_ms"], t["step_ms"],
                     t["scan_ms"], t["total_ms"], 1e3 / t["total_ms"], t["scan_compile_s"],
                     sum(t["stage_compile_s"].values()), t["peak_rss_mib_after_scan"]])
    L += [table(["sequence", "flow", "spatial", "temporal + ego", "step", "scan",
                 "total", "frames/s", "scan compile [s]", "stage compile [s]",
                 "peak RSS [MiB]"], rows, [0] + [1] * 7 + [1, 1, 0]), ""]
    L += [("Peers: median milliseconds per frame pair of the odometry call itself (frame "
          "preparation excluded), and that time / jaxvo's total per frame."), ""]
    rows = []
    for s, d in seqs.items():
        row = [s, d["timing"][JAXVO]["total_ms"]]
        for p in peers:
            ms = d["timing"][p]["ms"]
            row += [ms, ms / d["timing"][JAXVO]["total_ms"]]
        rows.append(row)
    hdr = ["sequence", "jaxvo [ms]"]
    for p in peers:
        hdr += [f"{p} [ms]", f"{p} / jaxvo"]
    L += [table(hdr, rows, [0, 1] + [1, 2] * len(peers)), ""]

    L += ["## Segmentation as a plug-in (thesis Fig. 5.8)", ""]
    L += [("Each peer alone and with jaxvo's dynamic-pixel mask. *gain* = ATE alone / ATE "
          "with the mask (> 1: the mask helps). Where jaxvo labelled no pixel dynamic the "
          "masked run would be the same run and is not repeated (marked *same*). *x true mask*: "
          "the peer with the true object masks of the synthetic / composite sequences (an "
          "upper bound of what any segmentation can give the peer; dotted in the figures)."), ""]
    rows = []
    for s in with_gt:
        d = seqs[s]
        for p in peers:
            a = (d["scores"].get(p) or {}).get("ate_rmse_m")
            b = (d["scores"].get(f"{p} x jaxvo") or {}).get("ate_rmse_m")
            ra = (d["scores"].get(p) or {}).get("rpe_trans_m_per_frame")
            rb = (d["scores"].get(f"{p} x jaxvo") or {}).get("rpe_trans_m_per_frame")
            o = (d["scores"].get(f"{p} x true mask") or {}).get("ate_rmse_m")
            rows.append([s, p, a, b, (a / b) if a and b else None, ra, rb,
                         "same" if d["plugin_same"] else f"{100 * d['dynamic_fraction']:.1f} %",
                         o, (a / o) if a and o else None])
    L += [table(["sequence", "peer", "ATE alone [m]", "ATE x jaxvo [m]", "gain",
                 "RPE alone [m/frame]", "RPE x jaxvo [m/frame]", "pixels masked",
                 "ATE x true mask [m]", "gain x true mask"], rows,
                [0, 0, 4, 4, 2, 4, 4, 0, 4, 2]), ""]

    L += ["## Figures", ""]
    for s, d in seqs.items():
        figs = ", ".join(f"[{Path(f).stem}]({f})" for f in d["figures"])
        L += [f"- **{s}**: {figs}"]
    L += [""]
    (out / "report.md").write_text("\n".join(L))


# ---------------------------------------------------------------------------------- main


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="fewer frames per sequence (default 40 instead of 90), ~5 min")
    ap.add_argument("--frames", type=int, metavar="N",
                    help="frames per synthetic / 7-Scenes sequence (default 90, --quick 40)")
    ap.add_argument("--out", default="results", metavar="DIR",
                    help="report folder (default results/)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the scenes and of jaxvo")
    ap.add_argument("--only", nargs="+", metavar="SEQ",
                    help="run only these sequences (names as in the report)")
    ap.add_argument("--repeats", type=int, default=3,
                    help="steady-state runs of the whole-sequence scan (median)")
    args = ap.parse_args(argv)
    frames = args.frames or (40 if args.quick else 90)
    out = Path(args.out)
    (out / "traj").mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    cfg = Config()
    peers = orbslam3_peer.all_peers()
    if orbslam3_peer.missing():
        log(f"ORB-SLAM3 skipped: {orbslam3_peer.missing()}")
    res = {
        "mode": "quick" if args.quick else "full",
        "command": "python bench/run.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "started": datetime.datetime.now().isoformat(timespec="seconds"),
        "frames": frames, "seed": args.seed, "machine": machine(), "peers": peers,
        "open3d": any(p in OPEN3D_PEERS for p in peers), "sequences": {},
        "orbslam3": orbslam3_peer.missing() or orbslam3_peer.vocabulary_note(),
    }
    seqs, res["skipped"] = build_sequences(frames, args.seed, args.only)
    for label, kind, seq in seqs:
        log(f"== {label}: {len(seq)} frames")
        d = {"kind": kind, "frames": len(seq), "duration_s": seq.duration,
             "height": seq.height, "width": seq.width,
             "groundtruth": seq.groundtruth is not None, "masks": seq.has_masks,
             "scores": {}, "failures": {}, "timing": {}, "figures": []}
        trajs = {}
        traj, outs, final_ids, timing = run_jaxvo(seq, cfg, args.seed, args.repeats)
        trajs[JAXVO] = traj
        d["timing"][JAXVO] = timing
        d["failures"][JAXVO] = int(np.count_nonzero(outs.status != Status.OK))
        d["scores"][JAXVO] = scores(seq, traj)
        if seq.has_masks:
            d["segmentation"] = segmentation_scores(seq, outs.moving, cfg.cell).as_dict()
        log(f"   jaxvo {timing['total_ms']:.1f} ms/frame, scan compile "
            f"{timing['scan_compile_s']:.1f} s, ATE {fmt((d['scores'][JAXVO] or {}).get('ate_rmse_m'))}")
        masks = dynamic_masks(outs, seq.height, seq.width, cfg.cell, final_ids=final_ids)
        d["dynamic_fraction"] = float(masks.mean())
        d["plugin_same"] = not masks.any()
        d["true_dynamic"] = bool(seq.has_masks and any((f.mask > 0).any() for f in seq))
        if seq.has_masks:
            d["mask_pixels"] = pixel_scores(seq, masks)
        for p in peers:
            r = orbslam3_peer.run_any_peer(seq, p)
            trajs[p] = r.trajectory
            d["timing"][p] = {"ms": r.ms_per_frame}
            d["failures"][p] = r.failures
            d["scores"][p] = scores(seq, r.trajectory)
            name = f"{p} x jaxvo"
            if d["plugin_same"]:
                rm = r
            else:
                rm = orbslam3_peer.run_any_peer(seq, p, keep=lambda i, m=masks: ~m[i])
            trajs[name] = rm.trajectory
            d["timing"][name] = {"ms": rm.ms_per_frame}
            d["failures"][name] = rm.failures
            d["scores"][name] = scores(seq, rm.trajectory)
            if seq.has_masks and seq.groundtruth is not None and d["true_dynamic"]:
                # the upper bound of the plug-in: the true object masks instead of jaxvo's
                ro = orbslam3_peer.run_any_peer(seq, p, keep=lambda i, s=seq: s[i].mask == 0)
                trajs[f"{p} x true mask"] = ro.trajectory
                d["failures"][f"{p} x true mask"] = ro.failures
                d["scores"][f"{p} x true mask"] = scores(seq, ro.trajectory)
            log(f"   {p}: {r.ms_per_frame:.0f} ms/frame, ATE "
                f"{fmt((d['scores'][p] or {}).get('ate_rmse_m'))} alone, "
                f"{fmt((d['scores'][name] or {}).get('ate_rmse_m'))} with jaxvo's mask")
        for name, tr in trajs.items():
            write_trajectory(out / "traj" / f"{label}__{name.replace(' ', '_')}.txt", tr)
        alone = {k: v for k, v in trajs.items() if " x " not in k}
        title = f"{label} ({len(seq)} frames)"
        f = f"traj_{label}.png"
        plot_trajectories(out / f, seq, alone, title)
        d["figures"].append(f)
        if seq.groundtruth is not None:
            f = f"error_{label}.png"
            plot_errors(out / f, seq, trajs, f"position error, {title}")
            d["figures"].append(f)
            if not d["plugin_same"] or d["true_dynamic"]:
                f = f"plugin_{label}.png"
                plot_trajectories(out / f, seq, {k: v for k, v in trajs.items() if k != JAXVO},
                                  f"peers alone, x jaxvo (dashed), x true mask (dotted), {title}")
                d["figures"].append(f)
        if seq.groundtruth is None:
            f = f"labels_peers_{label}.png"
            shown = alone if d["plugin_same"] else trajs
            plot_labels_and_peers(out / f, seq, shown, outs, cfg.cell,
                                  f"jaxvo's labels and every method's path, {title}")
            d["figures"].append(f)
        f = f"stages_{label}.png"
        d["panel_frames"] = stage_panels(out / f, seq, outs, cfg.cell)
        d["figures"].append(f)
        res["sequences"][label] = d
    res["machine"]["load_average_end"] = load_average()
    res["wall_s"] = time.perf_counter() - started
    (out / "results.json").write_text(json.dumps(res, indent=1, default=float))
    write_report(out, res)
    log(f"report: {out / 'report.md'} ({res['wall_s'] / 60:.1f} min)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
