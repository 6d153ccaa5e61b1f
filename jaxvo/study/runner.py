"""Studies over sequences, settings and seeds (host side): the runs, their scores and
resuming.

A study names sequences, configurations (``Params`` values, which one compiled call
batches, and ``Config`` values, each of which is its own compile) and seeds. Every
sequence's grid flow is computed once and cached on disk; every configuration of one
``Config`` then runs through :func:`jaxvo.core.pipeline.run_study`, the configurations dealt
out over every device of every process, each device vmapping ``batch`` configurations
(4 on the CPU; on an accelerator the widest call the study fills and its memory holds,
:func:`call_batch`). Each finished run is
scored at once (ATE, RPE, moving-object recall / precision / F where the sequence has
masks) and appended to ``runs.jsonl`` under the output folder, so an interrupted study
keeps what it finished and a resumed one runs only the rest. The tables, the summary over
seeds and the plots are written by :mod:`jaxvo.study.report`.

The parts live in their own modules: the spec in :mod:`jaxvo.study.spec`, the sequences
and their flow cache in :mod:`jaxvo.study.data`, the devices (processes, batch, compiled
programs, calls) in :mod:`jaxvo.study.devices`; this module runs them and re-exports
their public names (``from jaxvo.study import runner`` reaches the whole study).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxvo.config import Config, check_config
from jaxvo.errors import InputError
from jaxvo.host.writers.outputs import write_text
from jaxvo.status import Status
from jaxvo.study.data import (
    FLOW_FORMAT,
    SequenceData,
    flow_fields,
    open_study_sequence,
    sequence_data,
    sequence_identity,
    sequence_key,
    sequence_pairs,
)
from jaxvo.study.devices import (
    CPU_BATCH,
    MAX_ACCELERATOR_BATCH,
    MEMORY_SHARE,
    accelerator_batch,
    agree,
    batched_params,
    bytes_per_config,
    call_batch,
    compiled_program,
    free_memory,
    from_first,
    init_distributed,
    run_call,
    share_data,
    study_devices,
)
from jaxvo.study.spec import (
    DEFAULT_METRICS,
    METRICS,
    SequenceSpec,
    StudySpec,
    config_fields,
    group_config,
    load_spec,
    parse_spec,
)
from jaxvo.trajectory import Trajectory

__all__ = [
    "CPU_BATCH", "DEFAULT_METRICS", "FLOW_FORMAT", "MAX_ACCELERATOR_BATCH", "MEMORY_SHARE",
    "METRICS", "ROW_FIELDS", "RUNS_FILE", "Run", "SequenceData", "SequenceSpec", "StudyResult", "StudySpec",
    "accelerator_batch", "batched_params", "bytes_per_config", "call_batch", "check_study",
    "compiled_program", "config_fields", "finished_rows", "flow_fields",
    "free_memory", "group_config", "init_distributed", "load_spec", "open_study_sequence",
    "parse_spec", "read_runs", "run_call", "run_id", "run_spec", "score_run",
    "sequence_data", "sequence_identity", "sequence_key", "spec_runs", "study_devices",
]

RUNS_FILE = "runs.jsonl"


class Run(NamedTuple):
    """One run of a study: a sequence under one configuration and one seed."""

    sequence: int  # index into spec.sequences
    config: int  # index into spec.configs
    seed: int


def run_id(spec: StudySpec, run: Run) -> str:
    """A run's identity across resumed and changed specs: the sequence's identity (its spec
    and flow settings), every setting's value and the seed."""
    s = spec.sequences[run.sequence]
    settings = spec.configs[run.config]
    cfg = group_config(settings)
    blob = json.dumps({"sequence": sequence_key(s, cfg), "label": s.label,
                       "settings": settings, "seed": run.seed}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:20]


def score_run(data: SequenceData, T_w_c: np.ndarray, moving: np.ndarray,
              status: np.ndarray) -> dict:
    """Every metric of :data:`METRICS` (but ``seconds``) for one run; None where the
    sequence has no ground truth to score against.

    Args:
      T_w_c: (T, 4, 4) poses after each pair; moving: (T, n) bool; status: (T,) int.
    """
    from jaxvo.evaluation.metrics import SegmentationScores
    from jaxvo.evaluation.scores import trajectory_scores

    row: dict = dict.fromkeys(METRICS)
    # a fingerprint of the run's outputs: equal digests are equal bits (what the tests
    # compare across device and process counts)
    h = hashlib.sha256()
    for a in (T_w_c, moving, status):
        h.update(np.ascontiguousarray(a).tobytes())
    row["digest"] = h.hexdigest()[:16]
    row["skipped_pairs"] = int(np.count_nonzero(status != Status.OK))
    if data.groundtruth is not None:
        poses = np.concatenate([data.T_w_c0[None], np.asarray(T_w_c, np.float64)])
        try:
            scores = trajectory_scores(data.groundtruth, Trajectory(data.timestamps, poses))
        except InputError:  # e.g. too few poses associate with the ground truth
            scores = {}
        row.update({k: v for k, v in scores.items() if k in METRICS})
        row["ate_aligned"] = scores.get("ate_aligned")
    if data.truth is not None:
        seg = SegmentationScores()
        for pred, truth in zip(moving, data.truth, strict=True):
            seg.add(pred, truth)
        row.update(moving_recall=seg.recall, moving_precision=seg.precision,
                   moving_f=seg.f_measure)
    return row


class StudyResult(NamedTuple):
    """What :func:`run_spec` did."""

    rows: list[dict]  # one per run of the spec that has finished (this time or before)
    total: int  # runs the spec asks for
    ran: int  # runs done by this call
    config_frames: int  # configuration x frame pairs computed by this call
    seconds: float  # wall time of the device calls (compile included)
    # the first call of each compiled program (Config, grid, sequence length, batch), which
    # compiles it (and, on an accelerator, sizes its batch): its configuration x frame pairs
    # and wall time
    first_call_frames: int
    first_call_seconds: float
    flow_seconds: float  # host time computing flow (0 for cached flow)
    devices: int  # devices over every process
    processes: int
    batch: tuple[int, ...]  # configurations per device and call, each size used


def run_spec(spec: StudySpec, out_dir: str | Path, *, resume: bool = False,
             flow_cache: str | Path | None = None, batch: int | None = None,
             progress: Callable[[int, int], None] | None = None,
             log: Callable[[str], None] | None = None,
             stop: Callable[[], None] | None = None) -> StudyResult:
    """Run every (sequence, configuration, seed) of ``spec`` not yet in ``out_dir``.

    Every process of a multi-process study calls this with the same spec (after
    :func:`init_distributed`); the first process reads and writes ``out_dir`` and sends the
    others the flow and the list of runs left, so only it needs the data and the folder.

    Args:
      spec: a parsed study.
      out_dir: results folder; finished runs are appended to ``runs.jsonl`` there.
      resume: continue a study whose runs are already in ``out_dir`` (without it, such a
        folder is an error rather than mixed into).
      flow_cache: where the flows are cached (default ``out_dir/flows``).
      batch: configurations per device and call (default ``spec.batch``, else
        :func:`call_batch` sizes each program's calls from the device and the study).
      progress: called as ``progress(config_frames_done, config_frames_total)``.
      log: called with a line on each sequence's flow.
      stop: called between frames of the flow and between calls, where stopping keeps
        what finished (:func:`jaxvo.cli.main.interrupt_at_safe_points`'s request: it
        raises ``KeyboardInterrupt`` after a Ctrl-C); None: never.

    Returns:
      :class:`StudyResult`; the rows are those of the first process (others get none).
    """
    import jax

    out = Path(out_dir)
    first = jax.process_index() == 0
    sequence_key.cache_clear()  # a sequence's files may have changed since the last study
    cache = Path(flow_cache) if flow_cache is not None else out / "flows"
    requested = batch or spec.batch
    runs, ids = spec_runs(spec)
    done = _start(spec, out, cache, ids, resume=resume, requested=requested, first=first)
    devices = study_devices()
    # (sequence, Config) groups in spec order, each with its runs left
    groups: dict[tuple[int, Config], list[int]] = {}
    for k, r in enumerate(runs):
        if not done[k]:
            groups.setdefault((r.sequence, group_config(spec.configs[r.config])), []).append(k)
    pairs = {q: sequence_pairs(spec.sequences[q]) for q, _ in groups} if first else {}
    tally = _Tally(total=sum(len(ks) * pairs[q] for (q, _), ks in groups.items()) if first else 0)
    if first and log is not None:  # before the first flow and compile, which take minutes
        log(_plan_line(spec, groups, tally.total, runs=len(runs), devices=len(devices)))
    if progress is not None:
        progress(0, tally.total)
    for (q, cfg), ks in groups.items():
        data = _group_data(spec.sequences[q], cfg, cache, tally, first=first, log=log,
                           stop=stop)
        t0 = time.perf_counter()
        group_batch = call_batch(data, cfg, [spec.configs[runs[k].config] for k in ks],
                                 requested=requested, devices=devices)
        # an accelerator's sizing compiles the program: its time belongs to the first call
        sizing = time.perf_counter() - t0
        tally.batches.add(group_batch)
        per_call = group_batch * len(devices)
        for start in range(0, len(ks), per_call):
            chunk = [(ids[k], runs[k]) for k in ks[start:start + per_call]]
            t0 = time.perf_counter() - sizing
            sizing = 0.0
            outs = run_call(data, cfg, [spec.configs[r.config] for _, r in chunk],
                            [r.seed for _, r in chunk], devices=devices, batch=group_batch)
            tally.add_call(len(chunk), len(data.timestamps) - 1, time.perf_counter() - t0,
                           program=(cfg, data.flows.valid.shape, data.height, data.width,
                                    group_batch))
            if first:
                _append_runs(out / RUNS_FILE, _rows(spec, data, chunk, outs,
                                                     tally.last_seconds))
            if progress is not None:
                progress(tally.frames, tally.total)
            if stop is not None:
                stop()  # this call's runs are in runs.jsonl
    rows = finished_rows(spec, out) if first else []
    return StudyResult(rows, len(runs), tally.ran, tally.frames, tally.seconds,
                       tally.first_frames, tally.first_seconds, tally.flow_seconds,
                       len(devices), jax.process_count(), tuple(sorted(tally.batches)))


def _plan_line(spec: StudySpec, groups: dict, total: int, *, runs: int, devices: int) -> str:
    """What a study is about to do, said before its first flow and compile."""
    left = sum(len(ks) for ks in groups.values())
    return (f"{left} of {runs} runs to do ({len(spec.sequences)} sequences x "
            f"{len(spec.configs)} configurations x {len(spec.seeds)} seeds), "
            f"{total} configuration-frames over {devices} device(s); up to "
            f"{len(groups)} compile(s), one per sequence and Config, each in its first call "
            "(seconds to minutes); then the progress line gives the time left")


@dataclasses.dataclass
class _Tally:
    """What a study's calls have done so far (:class:`StudyResult`'s counters)."""

    total: int  # configuration-frames of the runs left (the progress total)
    ran: int = 0
    frames: int = 0
    seconds: float = 0.0
    flow_seconds: float = 0.0
    first_frames: int = 0  # of each program's first call, which compiles it
    first_seconds: float = 0.0
    last_seconds: float = 0.0
    batches: set = dataclasses.field(default_factory=set)
    programs: set = dataclasses.field(default_factory=set)

    def add_call(self, runs: int, pairs: int, seconds: float, *, program: tuple) -> None:
        self.ran += runs
        self.frames += runs * pairs
        self.seconds += seconds
        self.last_seconds = seconds
        if program not in self.programs:
            self.programs.add(program)
            self.first_frames += runs * pairs
            self.first_seconds += seconds


def _start(spec: StudySpec, out: Path, cache: Path, ids: list[str], *, resume: bool,
           requested: int | None, first: bool) -> np.ndarray:
    """Check the study on the first process (one line to every process on a problem), open
    its folder, and say on every process which runs are already done (bool per run)."""
    import jax

    done_ids: set[str] = set()
    problem = None
    if first:
        runs_path = out / RUNS_FILE
        try:  # a problem is told to every process, which all stop
            # host memory: the CPU's calls hold CPU_BATCH configurations; an
            # accelerator's calls are sized to its own memory (call_batch)
            check_study(spec, out, cache, requested or (
                CPU_BATCH if jax.default_backend() == "cpu" else 1))
            if runs_path.exists() and not runs_path.is_file():
                raise InputError(f"{runs_path}: is not a file; the study appends its runs there")
            if runs_path.is_file() and not resume:
                raise InputError(f"{out} already holds a study's runs ({RUNS_FILE}); pass "
                                 "--resume to continue it, or choose another --out")
        except InputError as exc:
            problem = exc
        else:
            done_ids = set(_finished(spec, runs_path)) if resume else set()
            out.mkdir(parents=True, exist_ok=True)
            write_text(out / "spec.json", json.dumps(_spec_record(spec), indent=1) + "\n")
    agree(problem)
    return from_first(np.asarray([i in done_ids for i in ids], bool))


def _group_data(s: SequenceSpec, cfg: Config, cache: Path, tally: _Tally, *, first: bool,
                log: Callable[[str], None] | None,
                stop: Callable[[], None] | None = None) -> SequenceData:
    """A sequence's flow under ``cfg`` on every process (read or computed by the first)."""
    data = problem = None
    if first:
        t0 = time.perf_counter()
        try:
            data, cached = sequence_data(s, cfg, cache, progress=None if stop is None else (
                lambda done, total: stop()))
        except InputError as exc:  # told to every process, which all stop
            problem = exc
        else:
            took = time.perf_counter() - t0
            tally.flow_seconds += 0.0 if cached else took
            if log is not None:
                log(f"{s.label}: {len(data.timestamps) - 1} frame pairs, flow " + (
                    "from the cache" if cached else f"in {took:.1f} s"))
    agree(problem)
    return share_data(data, cfg)


def _rows(spec: StudySpec, data: SequenceData, chunk: list[tuple[str, Run]], outs,
          seconds: float) -> list[dict]:
    """The table rows of one call's runs: identity, settings, seed and scores."""
    T_w_c, moving, status = outs
    rows = []
    for j, (run_id_, r) in enumerate(chunk):
        row = {"id": run_id_, "sequence": data.label, **spec.configs[r.config], "seed": r.seed,
               **score_run(data, T_w_c[j], moving[j], status[j])}
        row["seconds"] = seconds / len(chunk)
        rows.append(row)
    return rows


def spec_runs(spec: StudySpec) -> tuple[list[Run], list[str]]:
    """Every run of ``spec`` in order (sequence, then configuration, then seed) and its id."""
    runs = [Run(q, c, s) for q in range(len(spec.sequences)) for c in range(len(spec.configs))
            for s in spec.seeds]
    return runs, [run_id(spec, r) for r in runs]


def finished_rows(spec: StudySpec, out_dir: str | Path) -> list[dict]:
    """The rows of ``spec``'s runs already in ``out_dir``'s ``runs.jsonl``, in spec order."""
    finished = _finished(spec, Path(out_dir) / RUNS_FILE)
    return [finished[i] for i in spec_runs(spec)[1] if i in finished]


def check_study(spec: StudySpec, out_dir: str | Path, flow_cache: str | Path,
                batch: int) -> None:
    """Refuse, before any work, a study that cannot run: a sequence folder none of whose
    frames can be read (depth as JPEG, 8-bit PNGs), runs that need more memory than the
    machine has (a scene of 10^9 frames, ``num_hypotheses`` of 100000), or
    results and flows written over what the study reads (its spec, a sequence's files).

    Args:
      spec: the parsed study.
      out_dir, flow_cache: the results folder and the flow cache's.
      batch: configurations per device and call.
    Raises:
      InputError: one line naming the sequence, setting or folder.
    """
    from jaxvo.host.readers.io import check_outputs, first_readable
    from jaxvo.host.services.memory import (
        SYNTH_BYTES_PER_FRAME,
        SYNTH_BYTES_PER_OBJECT_FRAME,
        check_memory,
        run_bytes,
    )
    from jaxvo.synth.scenes import DEFAULT_FRAMES, SCENARIOS

    reads: list[Path] = [Path(spec.source)] if spec.source else []
    cfgs = {group_config(c) for c in spec.configs}
    side = min(batch, len(spec.configs) * len(spec.seeds))
    for s in spec.sequences:
        rendered = 0
        if s.path is None:
            frames, (height, width) = DEFAULT_FRAMES if s.frames is None else s.frames, (480, 640)
        else:
            from jaxvo.host.readers.io import open_sequence

            real = open_sequence(s.path, camera=s.camera)
            idx = range(0, len(real), s.step)
            frames, height, width = len(idx), real.height, real.width
            frames = frames if s.frames is None else min(frames, s.frames)
            reads += real.files((frames - 1) * s.step + 1)
            first_readable(((i, functools.partial(real.__getitem__, i)) for i in idx[:frames]),
                           where=f"sequence {s.label!r} ({s.path})", total=frames)
        if s.scene is not None:  # rendered: its trajectories held, every step-th frame used
            rendered = (frames - 1) * s.step + 1
        rendered_bytes = (SYNTH_BYTES_PER_FRAME + SYNTH_BYTES_PER_OBJECT_FRAME * len(
            SCENARIOS[s.scene].objects)) * rendered if s.scene else 0.0
        for cfg in cfgs:
            check_config(cfg, height=height, width=width)  # what needs the image size
            check_memory(run_bytes(cfg, height=height, width=width, frames=frames, configs=side,
                                   host_bytes=rendered_bytes),
                         what=f"sequence {s.label!r} ({frames} frames) with num_hypotheses "
                              f"{cfg.num_hypotheses}, {side} "
                              "configurations a call")
    check_outputs(reads, folders={"--out": Path(out_dir), "--flow-cache": Path(flow_cache)})


def _spec_record(spec: StudySpec) -> dict:
    rec = spec._asdict()
    rec["sequences"] = [q._asdict() for q in spec.sequences]
    rec["configs"] = list(spec.configs)
    return rec


# what every row of runs.jsonl holds (_rows, score_run); a line without them is no finished
# run of jaxvo study (a file written by hand or by another program)
ROW_FIELDS = ("id", "sequence", "seed", "digest")


def read_runs(path: str | Path) -> dict[str, dict]:
    """Finished runs by id from a ``runs.jsonl``. A line cut short by an interruption (no
    JSON) is ignored: that run is simply run again. A JSON line that is no row of a
    finished run (without :data:`ROW_FIELDS`: written by hand or by another program) is
    ignored too, with a warning that counts them (those runs run again)."""
    rows: dict[str, dict] = {}
    path = Path(path)
    if not path.is_file():
        return rows
    bad = 0
    for line in path.read_text().splitlines():
        try:
            row = json.loads(line)
        except ValueError:
            continue
        if isinstance(row, dict) and all(f in row for f in ROW_FIELDS):
            rows[row["id"]] = row
        else:
            bad += 1
    if bad:
        import warnings

        warnings.warn(f"{path}: {bad} line(s) hold no finished run (a row has "
                      f"{', '.join(ROW_FIELDS)} and its settings); ignored, those runs run "
                      "again", UserWarning, stacklevel=2)
    return rows


def _finished(spec: StudySpec, path: Path) -> dict[str, dict]:
    """The finished runs of ``runs.jsonl`` whose rows hold every setting of ``spec`` (what
    the tables read)."""
    return {i: row for i, row in read_runs(path).items()
            if all(k in row for k in spec.settings)}


def _append_runs(path: Path, rows: list[dict]) -> None:
    """Append one call's rows to ``runs.jsonl``, the one output a study appends to rather
    than replaces (a study of 10^5 runs would rewrite it 10^5 / batch times): each line is
    written whole or, cut by a kill, ignored when read (:func:`read_runs`). A failure (a
    full disk) names the file."""
    try:
        # a line cut short by a kill has no newline: end it, or the next row would join it
        cut = False
        if path.is_file() and path.stat().st_size > 0:
            with path.open("rb") as fh:
                fh.seek(-1, os.SEEK_END)
                cut = fh.read(1) != b"\n"
        with path.open("a") as fh:
            fh.write(("\n" if cut else "") + "".join(json.dumps(row) + "\n" for row in rows))
            fh.flush()
            os.fsync(fh.fileno())  # a finished call survives a kill that follows it
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror, str(path)) from None
