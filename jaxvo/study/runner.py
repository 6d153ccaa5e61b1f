"""Studies over sequences, settings and seeds (host side): the spec, the flow cache, the
sharded runs and their scores.

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

Numbers do not depend on how many devices or processes share the work: each device runs
one program, traced once and compiled for it alone (:func:`compiled_programs`: the same
machine code whatever the device count, with no partitioning pass and no XLA flag), on
the same ``batch`` consecutive configurations (padded to a whole number of calls; padding
is dropped); the same configuration vmapped in a batch of another size may differ in the
last bit.

The spec, in TOML (or the same structure in JSON)::

    name = "thesis parameters"
    seeds = [0, 1, 2]                  # PRNG seeds of the hypothesis sampling
    metrics = ["ate_rmse_m", "moving_f"]   # summarised and plotted (the table has all)
    batch = 4                          # configurations per device and call (optional)

    [[sequences]]                      # a built-in scene (jaxvo.synth.scenes.SCENARIOS)
    scene = "fixed_camera_1"
    frames = 40
    seed = 0                           # the scene's seed (textures, paths, noise)

    [[sequences]]                      # a TUM-layout folder (spec folder, else data root)
    path = "7scenes_static_0000_0299"
    frames = 100                       # the first 100 (optional), every `step`-th
    camera = "tum_fr1"                 # when the folder has no camera.txt

    [[sequences]]                      # a scene's moving boxes inserted into a folder
    composite = "7scenes_static_0000_0299"
    scene = "handheld_slow"

    [fixed]                            # values every configuration takes
    cell = 16                          # Config fields and Params fields alike
    [sweep]                            # one setting at a time around the base values
    lam = [100.0, 10000.0]
    [grid]                             # every combination
    max_age = [5.0, 30.0]
    num_hypotheses = [10, 20]          # a Config field: one compile per value
    [[points]]                         # explicit configurations
    lam = 300.0
    delta = 0.1

    [distributed]                      # several processes (also flags of `jaxvo study`)
    coordinator = "10.0.0.1:12345"
    num_processes = 2

Setting names are checked against ``Params._fields`` and the fields of ``Config`` when the
study starts, so the spec follows the pipeline's settings as they are renamed or added.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import inspect
import itertools
import json
import os
import re
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from jaxvo.config import Config, Params, check_config, check_param, grid_shape
from jaxvo.errors import InputError
from jaxvo.host.io import Trajectory, groundtruth_of_frames
from jaxvo.status import Status

# Columns of the results table: the scores of one run. ``moving_*`` need ground-truth
# masks, the trajectory scores ground truth, the per-second RPE a sequence over 1 s long.
METRICS = (
    "ate_rmse_m",
    "ate_max_m",
    "rpe_trans_m_per_frame",
    "rpe_rot_deg_per_frame",
    "rpe_trans_m_per_s",
    "rpe_rot_deg_per_s",
    "moving_recall",
    "moving_precision",
    "moving_f",
    "skipped_pairs",
    "seconds",
)
DEFAULT_METRICS = ("ate_rmse_m", "rpe_trans_m_per_frame", "moving_f")

_TOP_KEYS = ("name", "seeds", "metrics", "batch", "sequences", "fixed", "sweep", "grid",
             "points", "distributed")
_SEQUENCE_KEYS = ("name", "scene", "path", "composite", "frames", "seed", "step", "camera")
_DISTRIBUTED_KEYS = ("coordinator", "num_processes", "process_id")
RUNS_FILE = "runs.jsonl"


class SequenceSpec(NamedTuple):
    """One sequence of a study, as the spec names it."""

    label: str  # its name in the tables (unique within the study)
    scene: str | None  # built-in scene, or the scene whose boxes a composite inserts
    path: str | None  # TUM-layout folder (resolved), for a folder or a composite
    frames: int | None  # first frames used (None: all; built-in scenes: synth default)
    seed: int  # the scene's seed
    step: int  # every step-th frame
    camera: str | None  # intrinsics preset for a folder without camera.txt


class StudySpec(NamedTuple):
    """A parsed, validated study (see the module docstring for the file format)."""

    name: str
    sequences: tuple[SequenceSpec, ...]
    settings: tuple[str, ...]  # every setting the spec names; Config fields first
    base: dict  # setting -> its value when not swept (``fixed``, else the default)
    configs: tuple[dict, ...]  # setting -> value, one per configuration, in spec order
    swept: tuple[str, ...]  # settings that take more than one value
    seeds: tuple[int, ...]
    metrics: tuple[str, ...]  # the metrics summarised and plotted
    batch: int | None  # configurations per device and call (None: by backend)
    distributed: dict  # coordinator, num_processes, process_id as given
    source: str | None = None  # the spec's file (what the results must not overwrite)


# ----------------------------------------------------------------------------- the spec


def config_fields() -> dict[str, dataclasses.Field]:
    """``Config``'s fields by name (read at call time: the settings may change)."""
    return {f.name: f for f in dataclasses.fields(Config)}


def load_spec(path: str | Path, *, check_folders: bool = True) -> StudySpec:
    """Read and validate a study spec, TOML (``.toml``) or JSON (any other name).

    Relative sequence folders are looked up beside the spec, then under the data root
    (``check_folders``: as in :func:`parse_spec`).

    Raises:
      InputError: one line naming the file, the key and what is wrong with it.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise InputError(f"cannot read the study spec {path}: {exc.strerror}") from None
    try:
        if path.suffix.lower() == ".toml":
            import tomllib

            data = tomllib.loads(text)
        else:
            data = json.loads(text)
    except ValueError as exc:  # tomllib.TOMLDecodeError and json.JSONDecodeError
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"{path}: not valid {'TOML' if path.suffix == '.toml' else 'JSON'}: "
                         f"{first}") from None
    return parse_spec(data, where=str(path), base_dir=path.resolve().parent,
                      check_folders=check_folders)._replace(source=str(path))


def parse_spec(data: Any, *, where: str = "spec", base_dir: str | Path | None = None,
               check_folders: bool = True) -> StudySpec:
    """Validate a spec given as a dict (what TOML or JSON parse to).

    Args:
      data: the spec's top-level table.
      where: how error messages name the spec (its file name).
      base_dir: the folder relative sequence paths start from (default: the working one).
      check_folders: require every sequence folder to be there; the processes of a
        multi-process study other than the first take their flow from it and need none.

    Raises:
      InputError: ``"<where>: <key>: <what is wrong>"``, one line.
    """

    def bad(key: str, what: str) -> InputError:
        return InputError(f"{where}: {key}: {what}")

    if not isinstance(data, dict):
        raise InputError(f"{where}: the spec must be a table of keys, got {type(data).__name__}")
    for key in data:
        if key not in _TOP_KEYS:
            raise bad(key, f"unknown key; a study spec has {', '.join(_TOP_KEYS)}")
    name = data.get("name", Path(where).stem)
    if not isinstance(name, str) or not name:
        raise bad("name", "must be a non-empty string")

    seeds = data.get("seeds", [0])
    seeds = [seeds] if _is_int(seeds) else seeds
    # below 2^31: a seed is a 32-bit integer on the device (jax.random.key without x64)
    if not isinstance(seeds, list) or not seeds or not all(
            _is_int(s) and 0 <= s < 2**31 for s in seeds):
        raise bad("seeds", f"must be an integer in 0 .. 2^31 - 1 or a non-empty list of them, "
                           f"got {seeds!r}")
    if len(set(seeds)) != len(seeds):
        raise bad("seeds", f"repeats a seed: {seeds}")

    metrics = data.get("metrics", list(DEFAULT_METRICS))
    if not isinstance(metrics, list) or not metrics:
        raise bad("metrics", "must be a non-empty list of metric names")
    for m in metrics:
        if m not in METRICS:
            raise bad("metrics", f"unknown metric {m!r}; choose from {', '.join(METRICS)}")

    batch = data.get("batch")
    if batch is not None and not (_is_int(batch) and batch >= 1):
        raise bad("batch", f"must be a positive integer (configurations per device and call), "
                           f"got {batch!r}")

    distributed = data.get("distributed", {})
    if not isinstance(distributed, dict):
        raise bad("distributed", "must be a table (coordinator, num_processes, process_id)")
    for key, value in distributed.items():
        if key not in _DISTRIBUTED_KEYS:
            raise bad(f"distributed.{key}", f"unknown key; choose from "
                                            f"{', '.join(_DISTRIBUTED_KEYS)}")
        ok = isinstance(value, str) and ":" in value if key == "coordinator" else (
            _is_int(value) and value >= (1 if key == "num_processes" else 0))
        if not ok:
            raise bad(f"distributed.{key}", f"bad value {value!r}" + (
                " (expected HOST:PORT)" if key == "coordinator" else ""))

    sequences = _parse_sequences(data.get("sequences"), bad, Path(base_dir or "."),
                                 check_folders=check_folders)
    settings, base, configs, swept = _parse_configs(data, bad)
    return StudySpec(name, sequences, settings, base, configs, swept, tuple(seeds),
                     tuple(metrics), batch, dict(distributed))


def _is_int(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _parse_sequences(entries, bad, base_dir: Path, *,
                     check_folders: bool) -> tuple[SequenceSpec, ...]:
    from jaxvo.host.camera import PRESETS
    from jaxvo.synth.scenes import SCENARIOS

    if not isinstance(entries, list) or not entries:
        raise bad("sequences", "must be a non-empty list of tables ([[sequences]] in TOML)")
    out: list[SequenceSpec] = []
    for i, s in enumerate(entries):
        at = f"sequences[{i}]"
        if not isinstance(s, dict):
            raise bad(at, "must be a table")
        for key in s:
            if key not in _SEQUENCE_KEYS:
                raise bad(f"{at}.{key}", f"unknown key; a sequence has "
                                         f"{', '.join(_SEQUENCE_KEYS)}")
        kinds = [k for k in ("path", "composite") if k in s]
        if len(kinds) > 1:
            raise bad(at, "give either path (a folder) or composite (a folder with a scene's "
                          "boxes inserted), not both")
        if not kinds and "scene" not in s:
            raise bad(at, "needs scene (a built-in scene), path (a TUM-layout folder) or "
                          "composite (a folder and a scene)")
        scene = s.get("scene")
        if scene is not None and scene not in SCENARIOS:
            raise bad(f"{at}.scene", f"unknown scene {scene!r}; choose from "
                                     f"{', '.join(SCENARIOS)}")
        if "path" in s and scene is not None:
            raise bad(f"{at}.scene", "a folder (path) takes no scene; use composite to insert "
                                     "a scene's boxes into it")
        if "composite" in s and scene is None:
            raise bad(f"{at}.scene", "a composite needs the scene whose boxes it inserts")
        for key, least in (("frames", 2), ("seed", 0), ("step", 1)):
            if key in s and not (_is_int(s[key]) and s[key] >= least):
                raise bad(f"{at}.{key}", f"must be an integer >= {least}, got {s[key]!r}")
        camera = s.get("camera")
        if camera is not None:
            if not kinds:
                raise bad(f"{at}.camera", "only a folder (path, composite) takes a camera")
            if camera not in PRESETS:
                raise bad(f"{at}.camera", f"unknown preset {camera!r}; choose from "
                                          f"{', '.join(sorted(PRESETS))}")
        folder = None
        if kinds:
            given = s[kinds[0]]
            if not isinstance(given, str) or not given:
                raise bad(f"{at}.{kinds[0]}", "must be a folder name")
            folder = _resolve_folder(given, base_dir)
            if folder is None and not check_folders:
                folder = given
            elif folder is None:
                from jaxvo.host.io import data_root

                raise bad(f"{at}.{kinds[0]}", f"no folder {given!r} beside the spec "
                                              f"({base_dir}) or under the data root "
                                              f"({data_root()})")
        seed, step = s.get("seed", 0), s.get("step", 1)
        label = s.get("name") or _default_label(scene, folder, seed, step, composite=bool(
            "composite" in s))
        if not isinstance(label, str):
            raise bad(f"{at}.name", "must be a string")
        earlier = [j for j, o in enumerate(out) if o.label == label]
        if earlier:
            raise bad(at, f"its name {label!r} is that of sequences[{earlier[0]}]; give one of "
                          "them another name")
        out.append(SequenceSpec(label, scene, folder, s.get("frames"), seed, step, camera))
    return tuple(out)


def _resolve_folder(given: str, base_dir: Path) -> str | None:
    """A sequence folder (or ROS bag): as given when absolute, else beside the spec, else
    under the data root (None when there is none)."""
    from jaxvo.host.io import data_root
    from jaxvo.host.rosbag import is_bag

    p = Path(given).expanduser()
    for folder in ([p] if p.is_absolute() else [base_dir / p, data_root() / p]):
        if folder.is_dir() or is_bag(folder):
            return str(folder.resolve())
    return None


def _default_label(scene, folder, seed, step, *, composite: bool) -> str:
    every = f"_every{step}" if step > 1 else ""
    if folder is None:
        return f"{scene}_s{seed}{every}"
    name = Path(folder).name
    return f"composite_{scene}_{name}_s{seed}{every}" if composite else f"{name}{every}"


def _check_value(key: str, value, bad, *, at: str):
    """The value of setting ``key`` (``at`` names it in errors), checked against the type
    of its Params or Config field."""
    fields = config_fields()
    if key in Params._fields:
        if not isinstance(value, int | float) or isinstance(value, bool):
            raise bad(at, f"a Params value must be a number, got {value!r}")
        try:
            check_param(key, value, name="the value")
        except InputError as e:
            raise bad(at, str(e)) from None
        return float(value)
    if key in fields:
        allowed = _annotation_types(fields[key].type)
        if isinstance(value, bool) and bool not in allowed:
            raise bad(at, f"a Config value of type {fields[key].type} cannot be {value!r}")
        if float in allowed and _is_int(value):
            return float(value)
        if not isinstance(value, allowed):
            raise bad(at, f"a Config value of type {fields[key].type} cannot be {value!r}")
        return value
    raise bad(at, f"unknown setting; Params has {', '.join(Params._fields)}; Config has "
                  f"{', '.join(fields)}")


def _annotation_types(annotation) -> tuple[type, ...]:
    """Python types a dataclass field's annotation (a string under postponed evaluation,
    e.g. ``"int | None"``) admits."""
    names = {"int": int, "float": float, "bool": bool, "str": str, "None": type(None)}
    parts = [p.strip() for p in str(annotation).split("|")]
    return tuple(names[p] for p in parts if p in names) or (object,)


def _parse_configs(data, bad):
    """(settings, base, configs, swept) from the ``fixed``, ``sweep``, ``grid`` and
    ``points`` tables."""
    tables = {}
    for part in ("fixed", "sweep", "grid"):
        t = data.get(part, {})
        if not isinstance(t, dict):
            raise bad(part, "must be a table of setting = value(s)")
        tables[part] = t
    points = data.get("points", [])
    if not isinstance(points, list) or not all(isinstance(p, dict) for p in points):
        raise bad("points", "must be a list of tables ([[points]] in TOML)")

    fixed = {k: _check_value(k, v, bad, at=f"fixed.{k}") for k, v in tables["fixed"].items()}
    lists = {}
    for part in ("sweep", "grid"):
        for k, v in tables[part].items():
            values = v if isinstance(v, list) else [v]
            if not values:
                raise bad(f"{part}.{k}", "is an empty list")
            lists[(part, k)] = [_check_value(k, x, bad, at=f"{part}.{k}") for x in values]
            if len(set(map(repr, lists[(part, k)]))) != len(values):
                raise bad(f"{part}.{k}", f"repeats a value: {v}")
    point_values = [{k: _check_value(k, v, bad, at=f"points[{i}].{k}") for k, v in p.items()}
                    for i, p in enumerate(points)]
    for key in set(tables["sweep"]) & set(tables["grid"]):
        raise bad(f"grid.{key}", "is also in sweep; a setting is swept one way")
    for key in set(fixed) & (set(tables["sweep"]) | set(tables["grid"])):
        raise bad(f"fixed.{key}", "is also swept")

    named = set(fixed) | set(tables["sweep"]) | set(tables["grid"])
    named |= {k for p in point_values for k in p}
    cfg_names = [f for f in config_fields() if f in named]
    settings = tuple(cfg_names + [f for f in Params._fields if f in named])
    defaults = {**dataclasses.asdict(Config()), **Params()._asdict()}
    base = {k: fixed.get(k, defaults[k]) for k in settings}

    configs: list[dict] = []
    grid_keys = list(tables["grid"])
    for combo in itertools.product(*(lists[("grid", k)] for k in grid_keys)):
        around = {**base, **dict(zip(grid_keys, combo, strict=True))}
        configs.append(around)
        for k in tables["sweep"]:
            configs += [{**around, k: v} for v in lists[("sweep", k)]]
    configs += [{**base, **p} for p in point_values]
    # the first of each distinct configuration, in spec order: keyed by its values' reprs
    # (a dict lookup, not a scan of those kept, which took 15 s for 32,768 configurations)
    by_key: dict[tuple, dict] = {}
    for c in configs:
        by_key.setdefault(tuple(repr(c[k]) for k in settings), c)
    unique = list(by_key.values())
    # Config values no run can use (a window of 1 frame, ...), each combination checked once
    checked: set[tuple] = set()
    for c in unique:
        key = tuple(repr(c[k]) for k in cfg_names)
        if key in checked:
            continue
        checked.add(key)
        try:
            check_config(group_config(c))
        except InputError as e:
            raise bad("configuration " + ", ".join(f"{k} = {c[k]}" for k in config_fields()
                                                   if k in c), str(e)) from None
    swept = tuple(k for k in settings if len({repr(c[k]) for c in unique}) > 1)
    return settings, base, tuple(unique), swept


# ------------------------------------------------------------------- sequences and flow


class SequenceData(NamedTuple):
    """What a study needs of one sequence: its flow and what its runs are scored against."""

    label: str
    flows: Any  # GridFlow of numpy arrays, stacked over T pairs
    T_w_c0: np.ndarray  # (4, 4) float64 first camera pose (ground truth's, else identity)
    timestamps: np.ndarray  # (T + 1,) float64 seconds
    groundtruth: Trajectory | None  # camera-to-world ground truth, None without
    truth: np.ndarray | None  # (T, n) bool moving ground truth at the grid, None without masks
    height: int
    width: int


def open_study_sequence(s: SequenceSpec):
    """The sequence ``s`` names (frames are read or rendered lazily, when flow asks)."""
    from jaxvo.host.io import open_sequence
    from jaxvo.synth.scenes import DEFAULT_FRAMES, composite_sequence, make_sequence

    if s.path is None:
        frames = DEFAULT_FRAMES if s.frames is None else s.frames
        seq = make_sequence(s.scene, frames=(frames - 1) * s.step + 1, seed=s.seed)
    elif s.scene is not None:
        seq = composite_sequence(open_sequence(s.path, camera=s.camera), s.scene, seed=s.seed,
                                 frames=None if s.frames is None else (s.frames - 1) * s.step + 1)
    else:
        seq = open_sequence(s.path, camera=s.camera)
    return _Subset(seq, s.label, frames=s.frames, step=s.step)


class _Subset:
    """Every ``step``-th of the first frames of a sequence, lazily; it keeps each frame's
    moving ground truth at the grid as the flow reads the frames (rendering a synthetic
    frame costs 0.1 s, so it is read once)."""

    def __init__(self, seq, label: str, *, frames: int | None, step: int):
        idx = np.arange(0, len(seq), step)
        self._seq, self._idx = seq, idx if frames is None else idx[:frames]
        self.name, self.intrinsics = label, seq.intrinsics
        self.height, self.width = seq.height, seq.width
        self.timestamps = np.asarray(seq.timestamps, np.float64)[self._idx]
        self.groundtruth = groundtruth_of_frames(seq, self._idx)
        self.cell: int | None = None
        self.truth: dict[int, np.ndarray | None] = {}

    def __len__(self) -> int:
        return len(self._idx)

    def __getitem__(self, i: int):
        from jaxvo.host.masks import moving_at_grid

        frame = self._seq[int(self._idx[i])]
        if self.cell is not None:
            self.truth[i] = None if frame.mask is None else moving_at_grid(frame.mask, self.cell)
        return frame


@functools.cache
def flow_fields() -> tuple[str, ...]:
    """The ``Config`` fields the grid flow reads (those its cache is keyed by).

    Read off the source of :mod:`jaxvo.host.flow` (every ``cfg.<field>``), so a field that the
    flow starts to read keys the cache without anyone listing it here; the tests check
    the list against the fields a real flow computation reads.
    """
    import jaxvo.host.flow

    used = set(re.findall(r"\bcfg\.(\w+)", inspect.getsource(jaxvo.host.flow)))
    return tuple(f for f in config_fields() if f in used)


@functools.cache
def code_hash() -> str:
    """A hash of the code that makes frames and flow: a cache written by other code is
    not reused."""
    import jaxvo.host.flow
    import jaxvo.host.io
    import jaxvo.synth.render
    import jaxvo.synth.scenes

    h = hashlib.sha256()
    for mod in (jaxvo.host.flow, jaxvo.host.io, jaxvo.synth.render, jaxvo.synth.scenes):
        h.update(inspect.getsource(mod).encode())
    h.update(inspect.getsource(sequence_data).encode())  # what it stores beside the flow
    return h.hexdigest()[:16]


@functools.cache
def sequence_key(s: SequenceSpec, cfg: Config) -> str:
    """The flow cache's key of a sequence under ``cfg``: the sequence's identity (its spec,
    the contents of a folder's frame lists, or a bag's file sizes and modification times),
    the flow's Config fields and the code."""
    ident = {**s._asdict(), "flow": {f: getattr(cfg, f) for f in flow_fields()},
             "code": code_hash()}
    ident.pop("label")
    from jaxvo.host.rosbag import is_bag

    if s.path is not None and is_bag(s.path):  # too large to hash: its files' sizes and times
        files = [Path(s.path)] if Path(s.path).is_file() else sorted(Path(s.path).iterdir())
        ident["bag"] = [(f.name, f.stat().st_size, f.stat().st_mtime_ns) for f in files]
    elif s.path is not None:
        lists = sorted(p for p in Path(s.path).glob("*.txt"))
        ident["lists"] = hashlib.sha256(b"".join(p.read_bytes() for p in lists)).hexdigest()
    blob = json.dumps(ident, sort_keys=True).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def sequence_data(s: SequenceSpec, cfg: Config, cache_dir: str | Path | None, *,
                  progress: Callable[[int, int], None] | None = None) -> tuple[SequenceData, bool]:
    """The flow and scoring data of ``s`` under ``cfg``, from the cache when it is there.

    Returns:
      ``(data, cached)``: ``cached`` says whether it came from ``cache_dir``.
    """
    from jaxvo.host.flow import GridFlow, sequence_flows
    from jaxvo.odometry import choose_start_pose

    path = None
    if cache_dir is not None:
        path = Path(cache_dir) / f"{_safe(s.label)}-{sequence_key(s, cfg)}.npz"
        if path.is_file():
            z = np.load(path)
            gt = Trajectory(z["gt_t"], z["gt_poses"]) if "gt_t" in z else None
            return SequenceData(s.label, GridFlow(*(z[f] for f in GridFlow._fields)),
                                z["T_w_c0"], z["timestamps"], gt,
                                z.get("truth"), int(z["height"]),
                                int(z["width"])), True
    seq = open_study_sequence(s)
    if len(seq) < 2:
        raise InputError(f"sequence {s.label!r} has {len(seq)} frame(s); odometry needs 2")
    seq.cell = cfg.cell
    grid_shape(seq.height, seq.width, cfg.cell)  # an impossible cell fails here, in one line
    # frames that cannot be used are dropped and the next pairs with the last good one, as
    # in run_sequence: the kept frames' timestamps, start pose and masks go with the pairs
    chain = sequence_flows(seq, cfg, progress=progress)
    if len(chain.frames) < 2:
        reasons = "; ".join(sorted(set(chain.dropped.values())))
        raise InputError(f"sequence {s.label!r}: fewer than 2 frames can be used "
                         f"({len(chain.dropped)} dropped: {reasons})")
    kept = np.asarray(chain.frames)
    stamps = np.asarray(seq.timestamps, np.float64)[kept]
    gt = seq.groundtruth
    masks = [seq.truth.get(int(k)) for k in kept[:-1]]  # pair k is anchored on its first image
    truth = None if any(m is None for m in masks) else np.stack(masks)
    T_w_c0, _ = choose_start_pose("gt", gt, stamps[0])
    data = SequenceData(s.label, chain.flows, T_w_c0, stamps, gt, truth, seq.height,
                        seq.width)
    if path is not None:
        arrays = {**chain.flows._asdict(), "T_w_c0": data.T_w_c0, "timestamps": data.timestamps,
                  "height": data.height, "width": data.width}
        if gt is not None:
            arrays.update(gt_t=gt.timestamps, gt_poses=gt.poses)
        if truth is not None:
            arrays["truth"] = truth
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.npz")
        np.savez(tmp, **arrays)
        os.replace(tmp, path)  # whole or absent, also with several writers
    return data, False


def _safe(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", label)


# ------------------------------------------------------------------------- the runs


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


def group_config(settings: dict) -> Config:
    """The ``Config`` of a configuration (its Config fields over the defaults)."""
    fields = config_fields()
    return dataclasses.replace(Config(), **{k: v for k, v in settings.items() if k in fields})


def batched_params(configs: list[dict]):
    """``Params`` of numpy float32 (B,) arrays, one entry per configuration."""
    from jaxvo.core.pipeline import batch_params

    sweeps = {f: [c.get(f, getattr(Params(), f)) for c in configs] for f in Params._fields}
    return Params(*(np.asarray(a) for a in batch_params(Params(), **sweeps)))


# Configurations per device and call on the CPU: a vmapped call is no faster per
# configuration than one scan there (docs/report/study.md: a 32-configuration study at 4
# ran 0.89x the best batch), so small calls keep the padding and the resume granularity
# small. Accelerators size theirs from the device and the study (accelerator_batch).
CPU_BATCH = 4


# The largest share of a device's free memory one call may take, and the widest call. On an
# H200 a 60-frame scene ran 3.3k configuration-frames/s at 64 configurations a call, 9.8k
# at 256, 38k at 1024 and 83k at 4096 (issue 30): an accelerator wants the widest call the
# study and the memory allow.
MEMORY_SHARE = 0.5
MAX_ACCELERATOR_BATCH = 16384


def accelerator_batch(configs_per_device: int, bytes_per_config: float | None,
                      free_bytes: float | None) -> int:
    """Configurations per device and call on an accelerator: every configuration of the
    study in one call (a power of two at or above it, so that studies of nearby sizes share
    a compiled program), no wider than :data:`MEMORY_SHARE` of the free memory at
    ``bytes_per_config`` allows.

    Args:
      configs_per_device: the study's runs of one program, divided over the devices.
      bytes_per_config: device memory one configuration of the call needs (the compiled
        program's arguments, outputs and temporaries over its batch), None when unknown.
      free_bytes: the device's free memory, None when it does not say.
    """
    batch = 1 << max(0, int(configs_per_device) - 1).bit_length()
    batch = min(batch, MAX_ACCELERATOR_BATCH)
    if bytes_per_config and free_bytes:
        fits = int(MEMORY_SHARE * free_bytes // bytes_per_config)
        while batch > 1 and batch > fits:
            batch //= 2
    return batch


def free_memory(device) -> float | None:
    """Bytes free on ``device`` (None where its backend keeps no statistics, as the CPU)."""
    try:
        stats = device.memory_stats()
    except Exception:  # noqa: BLE001 - backends without statistics raise or return None
        return None
    if not stats or "bytes_limit" not in stats:
        return None
    return float(stats["bytes_limit"] - stats.get("bytes_in_use", 0))


def init_distributed(coordinator: str | None, num_processes: int | None,
                     process_id: int | None) -> None:
    """Join a multi-process study (``jax.distributed``) when more than one process is
    asked for; call before JAX touches a device.

    On the CPU the processes exchange data over Gloo (JAX's default CPU collectives).
    """
    if not num_processes or num_processes == 1:
        return
    if coordinator is None or process_id is None:
        raise InputError("a study over several processes needs the coordinator (HOST:PORT) "
                         "and this process's id (0 .. num_processes - 1)")
    if not 0 <= process_id < num_processes:
        raise InputError(f"process id {process_id} is not in 0 .. {num_processes - 1}")
    import jax

    if jax.config.jax_cpu_collectives_implementation is None:  # JAX before 0.5 had none
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(coordinator_address=coordinator, num_processes=num_processes,
                               process_id=process_id)


def study_devices() -> list:
    """Every device of every process, in the order the configurations are dealt out:
    process by process, each process's own devices in JAX's order."""
    import jax

    return sorted(jax.devices(), key=lambda d: (d.process_index, d.id))


@functools.cache
def _study_program(cfg: Config, grid: tuple[int, int]):
    """``run_study`` of a batch of configurations on one device, jitted; returns
    ``(T_w_c, moving, status)`` stacked over the configurations."""
    import jax

    from jaxvo.core.pipeline import run_study
    from jaxvo.core.window import window_trajectory

    def one_device(flows, T_w_c0, seeds, params):
        keys = jax.vmap(jax.random.key)(seeds)
        out = run_study(flows, keys, params, T_w_c0, cfg=cfg, grid=grid)
        T_w_c = out.T_w_c
        if cfg.window:  # each frame's final pose, from when it left the window
            T_w_c = jax.vmap(window_trajectory)(out.window)[:, 1:]
        return T_w_c, out.moving, out.status

    return jax.jit(one_device)


def _call_args(data: SequenceData, configs: list[dict], seeds: np.ndarray):
    """The host arguments of one device's call: the flow, the start pose, its seeds and its
    configurations' ``Params``."""
    return (data.flows, data.T_w_c0.astype(np.float32), seeds, batched_params(configs))


_compiled: dict[tuple, Any] = {}


def compiled_programs(cfg: Config, grid: tuple[int, int], args, devices) -> list:
    """The study program compiled for each of ``devices`` from one traced program (the
    same HLO and options but for the device: the same machine code, so the same bits on
    every device and device count), compiled concurrently, loaded from the persistent
    compile cache where it is there. ``args`` are one device's host arguments."""
    import jax
    from jax.sharding import SingleDeviceSharding

    fn = _study_program(cfg, grid)
    shapes = jax.tree.map(lambda a: (np.shape(a), np.asarray(a).dtype), args)
    keys = [(cfg, grid, str(shapes), d) for d in devices]
    missing = [(k, d) for k, d in zip(keys, devices, strict=True) if k not in _compiled]
    lowered = [fn.lower(*jax.tree.map(
        lambda a, d=d: jax.ShapeDtypeStruct(np.shape(a), np.asarray(a).dtype,
                                            sharding=SingleDeviceSharding(d)), args))
        for _, d in missing]
    with ThreadPoolExecutor(max(1, len(lowered))) as pool:  # XLA compiles without the GIL
        for (k, _), exe in zip(missing, pool.map(lambda low: low.compile(), lowered),
                               strict=True):
            _compiled[k] = exe
    return [_compiled[k] for k in keys]


def bytes_per_config(executable, batch: int) -> float | None:
    """Device memory one configuration of a compiled call needs (its arguments, outputs and
    temporaries over the batch); None where the backend does not say."""
    try:
        m = executable.memory_analysis()
    except Exception:  # noqa: BLE001 - not every backend analyses memory
        return None
    if m is None:
        return None
    total = (m.argument_size_in_bytes + m.output_size_in_bytes + m.temp_size_in_bytes
             - m.alias_size_in_bytes)
    return total / batch


def call_batch(data: SequenceData, cfg: Config, configs: list[dict], *, requested: int | None,
               devices: list) -> int:
    """Configurations per device and call for ``configs`` of one program: ``requested``
    (``--batch`` or the spec's) where given, 4 on the CPU, else the accelerator's widest
    call that the study fills and half its free memory holds (compiled at that width to
    read its memory need, then halved until it fits)."""
    if requested:
        return requested
    if devices[0].platform == "cpu":
        return CPU_BATCH
    import jax

    own = next(d for d in devices if d.process_index == jax.process_index())
    per_device = -(-len(configs) // len(devices))
    free = free_memory(own)
    batch = accelerator_batch(per_device, None, free)
    grid = grid_shape(data.height, data.width, cfg.cell)
    while True:
        args = _call_args(data, [configs[0]] * batch, np.zeros(batch, np.uint32))
        need = bytes_per_config(compiled_programs(cfg, grid, args, [own])[0], batch)
        fits = accelerator_batch(per_device, need, free)
        if fits >= batch:
            break
        batch = fits
    return int(_from_first(np.asarray([batch]))[0])  # every process calls alike


def _gather(local: np.ndarray) -> np.ndarray:
    """Every process's block of results, in process order, on every process."""
    import jax

    if jax.process_count() == 1:
        return local
    from jax.experimental import multihost_utils

    return np.asarray(multihost_utils.process_allgather(local, tiled=True))


def run_call(data: SequenceData, cfg: Config, configs: list[dict], seeds: list[int], *,
             devices: list, batch: int):
    """One call: configuration ``i`` with seed ``seeds[i]`` on ``data``'s flow.

    The list is padded with copies of its last entry to ``batch`` times the device count
    (the padding's results are dropped) and dealt out in order, ``batch`` consecutive
    configurations to each device of :func:`study_devices`; every device runs the same
    program (:func:`compiled_programs`), dispatched without waiting, so the devices work
    at once.

    Returns:
      ``(T_w_c (B, T, 4, 4) float32, moving (B, T, n) bool, status (B, T) int32)`` numpy.
    """
    import jax

    size = batch * len(devices)
    b = len(configs)
    if not 0 < b <= size or len(seeds) != b:
        raise ValueError(f"a call takes 1 to {size} configurations with one seed each, got "
                         f"{b} and {len(seeds)} seeds")
    configs = list(configs) + [configs[-1]] * (size - b)
    seeds = np.asarray(list(seeds) + [seeds[-1]] * (size - b), np.uint32)
    mine = [(k, d) for k, d in enumerate(devices) if d.process_index == jax.process_index()]
    args = [_call_args(data, configs[k * batch:(k + 1) * batch], seeds[k * batch:(k + 1) * batch])
            for k, _ in mine]
    grid = grid_shape(data.height, data.width, cfg.cell)
    programs = compiled_programs(cfg, grid, args[0], [d for _, d in mine])
    pending = [exe(*jax.device_put(a, d)) for exe, a, (_, d) in zip(programs, args, mine,
                                                                     strict=True)]
    outs = [np.concatenate([np.asarray(p[i]) for p in pending]) for i in range(3)]
    return tuple(_gather(o)[:b] for o in outs)


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
             log: Callable[[str], None] | None = None) -> StudyResult:
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

    Returns:
      :class:`StudyResult`; the rows are those of the first process (others get none).
    """
    import jax

    out = Path(out_dir)
    first = jax.process_index() == 0
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
    pairs = {q: _pairs(spec.sequences[q]) for q, _ in groups} if first else {}
    tally = _Tally(total=sum(len(ks) * pairs[q] for (q, _), ks in groups.items()) if first else 0)
    if progress is not None:
        progress(0, tally.total)
    for (q, cfg), ks in groups.items():
        data = _group_data(spec.sequences[q], cfg, cache, tally, first=first, log=log)
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
    rows = finished_rows(spec, out) if first else []
    return StudyResult(rows, len(runs), tally.ran, tally.frames, tally.seconds,
                       tally.first_frames, tally.first_seconds, tally.flow_seconds,
                       len(devices), jax.process_count(), tuple(sorted(tally.batches)))


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
            if runs_path.is_file() and not resume:
                raise InputError(f"{out} already holds a study's runs ({RUNS_FILE}); pass "
                                 "--resume to continue it, or choose another --out")
        except InputError as exc:
            problem = exc
        else:
            done_ids = set(read_runs(runs_path)) if resume else set()
            out.mkdir(parents=True, exist_ok=True)
            (out / "spec.json").write_text(json.dumps(_spec_record(spec), indent=1) + "\n")
    _agree(problem)
    return _from_first(np.asarray([i in done_ids for i in ids], bool))


def _group_data(s: SequenceSpec, cfg: Config, cache: Path, tally: _Tally, *, first: bool,
                log: Callable[[str], None] | None) -> SequenceData:
    """A sequence's flow under ``cfg`` on every process (read or computed by the first)."""
    data = problem = None
    if first:
        t0 = time.perf_counter()
        try:
            data, cached = sequence_data(s, cfg, cache)
        except InputError as exc:  # told to every process, which all stop
            problem = exc
        else:
            took = time.perf_counter() - t0
            tally.flow_seconds += 0.0 if cached else took
            if log is not None:
                log(f"{s.label}: {len(data.timestamps) - 1} frame pairs, flow " + (
                    "from the cache" if cached else f"in {took:.1f} s"))
    _agree(problem)
    return _share_data(data)


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
    finished = read_runs(Path(out_dir) / RUNS_FILE)
    return [finished[i] for i in spec_runs(spec)[1] if i in finished]


def check_study(spec: StudySpec, out_dir: str | Path, flow_cache: str | Path,
                batch: int) -> None:
    """Refuse, before any work, a study that cannot run: a sequence folder none of whose
    frames can be read (depth as JPEG, 8-bit PNGs), runs that need more memory than the
    machine has (a scene of 10^9 frames, ``num_hypotheses`` or ``window`` of 100000), or
    results and flows written over what the study reads (its spec, a sequence's files).

    Args:
      spec: the parsed study.
      out_dir, flow_cache: the results folder and the flow cache's.
      batch: configurations per device and call.
    Raises:
      InputError: one line naming the sequence, setting or folder.
    """
    from jaxvo.host.io import check_outputs, first_readable
    from jaxvo.host.memory import (
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
            from jaxvo.host.io import open_sequence

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
            check_memory(run_bytes(cfg, height=height, width=width, frames=frames, configs=side,
                                   host_bytes=rendered_bytes),
                         what=f"sequence {s.label!r} ({frames} frames) with num_hypotheses "
                              f"{cfg.num_hypotheses}, window {cfg.window}, {side} "
                              "configurations a call")
    check_outputs(reads, folders={"--out": Path(out_dir), "--flow-cache": Path(flow_cache)})


def _pairs(s: SequenceSpec) -> int:
    """Frame pairs of a sequence (for the progress total), without reading its frames."""
    if s.path is None:
        from jaxvo.synth.scenes import DEFAULT_FRAMES

        return (DEFAULT_FRAMES if s.frames is None else s.frames) - 1
    seq = open_study_sequence(s)
    return len(seq) - 1


def _spec_record(spec: StudySpec) -> dict:
    rec = spec._asdict()
    rec["sequences"] = [q._asdict() for q in spec.sequences]
    rec["configs"] = list(spec.configs)
    return rec


def read_runs(path: str | Path) -> dict[str, dict]:
    """Finished runs by id from a ``runs.jsonl`` (a line cut short by an interruption is
    ignored: that run is simply run again)."""
    rows: dict[str, dict] = {}
    path = Path(path)
    if not path.is_file():
        return rows
    for line in path.read_text().splitlines():
        try:
            row = json.loads(line)
        except ValueError:
            continue
        if isinstance(row, dict) and "id" in row:
            rows[row["id"]] = row
    return rows


def _append_runs(path: Path, rows: list[dict]) -> None:
    # a line cut short by a kill has no newline: end it, or the next row would join it
    cut = False
    if path.is_file() and path.stat().st_size > 0:
        with path.open("rb") as fh:
            fh.seek(-1, os.SEEK_END)
            cut = fh.read(1) != b"\n"
    with path.open("a") as fh:
        if cut:
            fh.write("\n")
        for row in rows:
            fh.write(json.dumps(row) + "\n")
        fh.flush()
        os.fsync(fh.fileno())  # a finished call survives a kill that follows it


def _from_first(x: np.ndarray) -> np.ndarray:
    """The first process's value of ``x`` on every process (the same shape everywhere)."""
    import jax

    if jax.process_count() == 1:
        return x
    from jax.experimental import multihost_utils

    return np.asarray(multihost_utils.broadcast_one_to_all(x))


def _agree(problem: InputError | None) -> None:
    """Raise the first process's ``problem`` on every process (the others would otherwise
    wait for it in the next exchange until JAX's timeout)."""
    if _from_first(np.asarray([problem is not None]))[0]:
        raise problem or InputError("the first process stopped the study; see its message")


def _share_data(data: SequenceData | None) -> SequenceData:
    """The first process's flow on every process: the others need neither the frames nor
    the cache, and every device computes on the same flow."""
    import jax

    if jax.process_count() == 1:
        return data
    from jaxvo.host.flow import GridFlow

    head = np.zeros(4, np.int64)
    if data is not None:
        T, n = data.flows.valid.shape
        head[:] = (T, n, data.height, data.width)
    T, n, h, w = (int(v) for v in _from_first(head))
    if data is None:
        flows = GridFlow(np.zeros((T, n, 3), np.float32), np.zeros((T, n, 3), np.float32),
                         np.zeros((T, n, 2), np.float32), np.zeros((T, n, 2), np.float32),
                         np.zeros((T, n), bool), np.zeros((T,), np.int32),
                         np.zeros((T,), np.float32), np.zeros((T, n), bool),
                         np.zeros((T, n), np.float32), np.zeros((T, n), np.float32))
        data = SequenceData("", flows, np.eye(4), np.zeros(T + 1), None, None, h, w)
    flows = GridFlow(*(_from_first(np.asarray(a)) for a in data.flows))
    T0 = _from_first(np.asarray(data.T_w_c0, np.float64))
    return data._replace(flows=flows, T_w_c0=T0)
