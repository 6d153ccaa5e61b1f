"""The sliding-window refinement (``Config.window``, issue 21): every bench case with and
without it, the peers beside them, and what it costs per frame.

Cases: every case of the development and validation splits (``bench/splits.py``) and
the whole 7-Scenes sequence (all 300 frames, and every 2nd and 4th frame: the issue's
static targets). For each, jaxvo's streaming step over the cached grid flow (the same
cache as ``bench/bench_robustness.py``) without and with the window: ATE (rigidly
aligned) and RPE per frame against ground truth, and the best OpenCV peer's ATE on the
same frames (Open3D where it imports is not run here: see ``bench/run.py``).

Cost: the jitted step with and without the window over the same flows, the two run
alternately ``--repeats`` times (each run over a whole case), medians of the per-frame
wall times, with the load average (the host is shared); and the peak resident memory of
``jaxvo run`` on the 300 7-Scenes frames with and without ``--window``.

Run: ``.venv/bin/python bench/bench_window.py [--window 5] [--only CASE ...]
[--skip-memory] [--out results/]``. Writes ``window.md`` and ``window.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import SEVEN_SCENES, load_average, log, machine, markdown_table
from bench_robustness import _fmt, peers_alone, prepare
from splits import Case, available, cases, runnable

from jaxvo.config import Config, Params, grid_shape, params_as_arrays
from jaxvo.core.pipeline import init_pipeline, jit_step
from jaxvo.core.window import window_trajectory
from jaxvo.evaluation.scores import trajectory_scores
from jaxvo.host.flow import GridFlow
from jaxvo.host.io import InMemorySequence, Trajectory, data_root, open_sequence


def full_cases() -> list[Case]:
    """The whole 7-Scenes sequence at every k-th frame (reported, never tuned on)."""

    def build(step):
        def make():
            seq = InMemorySequence(open_sequence(data_root() / SEVEN_SCENES), step=step)
            seq.name = f"{SEVEN_SCENES}_every{step}"
            return seq
        return make

    return [Case(f"7scenes_all_every{k}", "report", "static", SEVEN_SCENES, build(k))
            for k in (1, 2, 4)]


def run(data: dict, cfg: Config, seed: int = 0):
    """The streaming step over a case's cached flows: the trajectory (the window's final
    poses when it is on), the immediate one, and the wall time of each step, seconds."""
    h, w = (int(x) for x in data["size"])
    grid = grid_shape(h, w, cfg.cell)
    T0 = np.asarray(data.get("gt_poses", np.eye(4)[None])[0], np.float64)
    params = params_as_arrays(Params())
    state = init_pipeline(cfg=cfg, grid=grid, T_w_c0=T0, params=params)
    key = jax.random.key(seed)
    flows = GridFlow(*(data[f"flow_{k}"] for k in GridFlow._fields))
    outs, times = [], []
    for k in range(len(flows.valid)):
        flow = GridFlow(*(jnp.asarray(a[k]) for a in flows))
        t0 = time.perf_counter()
        state, out = jit_step(state, flow, key, params, cfg=cfg, grid=grid)
        jax.block_until_ready(out.T_w_c)
        times.append(time.perf_counter() - t0)
        outs.append(out)
    outs = jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *outs)
    immediate = np.concatenate([T0[None], outs.T_w_c.astype(np.float64)])
    poses = immediate
    if outs.window is not None:
        poses = np.asarray(window_trajectory(outs.window), np.float64)
        poses[0] = T0
    stamps = data["timestamps"]
    return Trajectory(stamps, poses), Trajectory(stamps, immediate), np.asarray(times)


def accuracy(case: Case, data: dict, cache: Path, K: int) -> dict:
    row = {"case": case.name, "split": case.split, "kind": case.kind,
           "pairs": len(data["flow_valid"])}
    gt = Trajectory(data["timestamps"], data["gt_poses"]) if "gt_poses" in data else None
    for label, cfg in (("off", Config()), ("on", dataclasses.replace(Config(), window=K))):
        traj, immediate, _ = run(data, cfg)
        if gt is None:
            continue
        s = trajectory_scores(gt, traj)
        row[f"ate_mm_{label}"] = 1e3 * s["ate_rmse_m"]
        row[f"rpe_mm_{label}"] = 1e3 * s["rpe_trans_m_per_frame"]
        row[f"rpe_deg_{label}"] = s["rpe_rot_deg_per_frame"]
        if label == "on":
            row["ate_mm_immediate"] = 1e3 * trajectory_scores(gt, immediate)["ate_rmse_m"]
    peers = peers_alone(case, cache) if gt is not None else {}
    if peers:
        best = min(peers, key=lambda k: peers[k]["ate_rmse_m"])
        row["best_peer"] = best
        row["best_peer_ate_mm"] = 1e3 * peers[best]["ate_rmse_m"]
    return row


def cost(data: dict, K: int, repeats: int) -> dict:
    """Per-frame wall time of the jitted step without and with the window, alternating
    whole runs (compile excluded: a first run of each is discarded)."""
    cfgs = {"off": Config(), "on": dataclasses.replace(Config(), window=K)}
    for cfg in cfgs.values():
        run(data, cfg)  # compile
    per_run = {k: [] for k in cfgs}
    loads = []
    for r in range(repeats):
        order = list(cfgs) if r % 2 == 0 else list(cfgs)[::-1]
        for label in order:
            per_run[label].append(1e3 * np.median(run(data, cfgs[label])[2][2:]))
        loads.append(load_average()[0] if load_average() else None)
    diffs = np.asarray(per_run["on"]) - np.asarray(per_run["off"])
    return {"ms_per_frame_off": [round(x, 3) for x in per_run["off"]],
            "ms_per_frame_on": [round(x, 3) for x in per_run["on"]],
            "median_off": round(float(np.median(per_run["off"])), 3),
            "median_on": round(float(np.median(per_run["on"])), 3),
            "median_paired_difference": round(float(np.median(diffs)), 3),
            "load_average_1min": loads}


def memory(K: int) -> dict:
    """Peak resident memory of ``jaxvo run`` on the 300 7-Scenes frames, without and
    with the window (each process reports its own VmHWM)."""
    seq_dir = data_root() / SEVEN_SCENES
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for label, extra in (("off", []), ("on", ["--window", str(K)])):
            proc = subprocess.run(
                [sys.executable, "-m", "jaxvo.cli.main", "run", str(seq_dir), "--out",
                 str(Path(tmp) / f"{label}.txt"), "-q", "--json", *extra],
                capture_output=True, text=True, check=False)
            if proc.returncode not in (0, 1):
                raise RuntimeError(proc.stderr)
            s = json.loads(proc.stdout)
            out[label] = {"peak_rss_mib": s["peak_rss_mib"], "ate_m": s.get("ate_rmse_m"),
                          "rpe_m_per_frame": s.get("rpe_trans_rmse_m_per_frame"),
                          "frames_per_second": s["frames_per_second"]}
    return out


def _f(x, spec=".1f"):
    return _fmt(x, spec)


def table(rows: list[dict]) -> str:
    head = ["case", "split", "ATE mm off", "ATE mm on", "on/off", "best peer mm", "on/peer",
            "RPE mm/frame off", "on", "RPE deg/frame off", "on"]
    cells = []
    for r in rows:
        off, on, peer = r.get("ate_mm_off"), r.get("ate_mm_on"), r.get("best_peer_ate_mm")
        cells.append([
            r["case"], r["split"], _f(off), _f(on), _f(on / off if off and on else None, ".2f"),
            _f(peer), _f(on / peer if peer and on else None, ".2f"),
            _f(r.get("rpe_mm_off"), ".2f"), _f(r.get("rpe_mm_on"), ".2f"),
            _f(r.get("rpe_deg_off"), ".3f"), _f(r.get("rpe_deg_on"), ".3f")])
    return markdown_table(head, cells)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--window", type=int, default=5, help="K frames (default 5)")
    ap.add_argument("--only", nargs="*", help="case names")
    ap.add_argument("--repeats", type=int, default=5, help="alternating runs for the cost")
    ap.add_argument("--cost-case", default="static_dev_every1")
    ap.add_argument("--skip-memory", action="store_true")
    ap.add_argument("--cache", type=Path, default=Path("results/cache"))
    ap.add_argument("--out", type=Path, default=Path("results"))
    args = ap.parse_args(argv)

    todo = [c for c in cases() + full_cases() if not args.only or c.name in args.only]
    rows = []
    todo, skipped = runnable(todo)
    for case in todo:
        data = prepare(case, args.cache, Config())
        rows.append(accuracy(case, data, args.cache, args.window))
        r = rows[-1]
        log(f"{case.name}: ATE {_f(r.get('ate_mm_off'))} -> {_f(r.get('ate_mm_on'))} mm, "
            f"RPE {_f(r.get('rpe_mm_off'), '.2f')} -> {_f(r.get('rpe_mm_on'), '.2f')} mm/frame, "
            f"best peer {_f(r.get('best_peer_ate_mm'))} mm")
    res = {"meta": {"date": datetime.datetime.now().isoformat(timespec="seconds"),
                    "machine": machine(), "window": args.window, "skipped": skipped},
           "rows": rows}
    cost_case = next((c for c in cases() if c.name == args.cost_case), None)
    if cost_case is not None and not available(cost_case):
        log(f"cost: {args.cost_case}, {args.repeats} alternating runs each")
        res["cost"] = {"case": args.cost_case,
                       **cost(prepare(cost_case, args.cache, Config()), args.window,
                              args.repeats)}
        log(f"cost: {res['cost']}")
    if not args.skip_memory and (data_root() / SEVEN_SCENES / "rgb.txt").is_file():
        res["memory"] = memory(args.window)
        log(f"memory: {res['memory']}")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "window.json").write_text(json.dumps(res, indent=1))
    m = res["meta"]
    md = [(f"# The sliding window (K = {args.window}) on every bench case\n\n{m['date']}; "
          f"{m['machine']['cpu_model']}; jax {m['machine']['jax']}\n"), table(rows)]
    if "cost" in res:
        c = res["cost"]
        md.append(f"\nStep cost on {c['case']}, medians of {len(c['ms_per_frame_off'])} "
                  f"alternating runs: {c['median_off']} ms a frame without the window, "
                  f"{c['median_on']} with it; median paired difference "
                  f"{c['median_paired_difference']} ms (load average {c['load_average_1min']})")
    if "memory" in res:
        mem = res["memory"]
        md.append(f"\n`jaxvo run` on all 300 7-Scenes frames: peak resident "
                  f"{mem['off']['peak_rss_mib']} MiB without the window, "
                  f"{mem['on']['peak_rss_mib']} MiB with it")
    for name, why in skipped.items():
        md.append(f"\n{name}: skipped, {why}")
    (args.out / "window.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
