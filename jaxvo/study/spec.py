"""A study's spec (host side): its file, its checks and its configurations.

A study names sequences, configurations (``Params`` values, which one compiled call
batches, and ``Config`` values, each of which is its own compile) and seeds.

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

import functools
import itertools
import json
from pathlib import Path
from typing import Any, NamedTuple

from jaxvo.config import Config, Params, check_config, check_param, config_fields
from jaxvo.errors import InputError

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
# settings that are gone, with what replaced them: the consecutive-frame window gave way
# to the local window over keyframes (jaxvo.core.keyframe)
_REPLACED = {"window": "keyframes = true, keyframe_window", "window_iters": "keyframe_iters"}


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
    from jaxvo.host.frontend.camera import PRESETS
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
                from jaxvo.host.readers.io import data_root

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
    from jaxvo.host.readers.io import data_root
    from jaxvo.host.readers.rosbag import is_bag

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
    if key in _REPLACED:
        raise bad(at, "the consecutive-frame window was removed; the window over keyframes "
                      f"replaces it: {_REPLACED[key]}")
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
    defaults = {**Config().as_dict(), **Params()._asdict()}
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
    # (a dict lookup, not a scan of those kept, which grew with the square of their number)
    by_key: dict[tuple, dict] = {}
    for c in configs:
        by_key.setdefault(tuple(repr(c[k]) for k in settings), c)
    unique = list(by_key.values())
    # Config values no run can use (a cell of 2 pixels, ...), each combination checked once
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


def group_config(settings: dict) -> Config:
    """The ``Config`` of a configuration (its Config fields over the defaults).

    A study asks it of every run; the Configs are few, so each is made once (a study of
    many configurations spent most of its start building the same few again)."""
    names = config_fields()  # every setting by name (a Config's own fields are its two sides)
    items = tuple((k, v) for k, v in settings.items() if k in names)
    try:
        return _config_of(items)
    except TypeError:  # a value that cannot key the memo: made afresh
        return Config(**dict(items))


@functools.lru_cache(maxsize=4096)
def _config_of(items: tuple) -> Config:
    return Config(**dict(items))
