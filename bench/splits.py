"""The development and validation splits: what jaxvo is tuned on, and what it is judged on.

Every rule and constant of the method is chosen on the **development** split only; the
**validation** split is run to report, never to choose. Real frames are split by time: the
development split uses frames 0-149 of the shared 7-Scenes sequence, the validation split
frames 150-299 and the TUM walking clip, which no development case reads.

| split | case | what it is |
| --- | --- | --- |
| dev | ``synth_<scenario>`` | the built-in synthetic scenes, seed 0, 90 frames |
| dev | ``comp_<scenario>_dev`` | boxes composited into 7-Scenes frames 0-149, seed 0 |
| dev | ``static_dev_every<k>`` | 7-Scenes frames 0-149 at every k-th frame: nothing moves |
| val | ``comp_<scenario>_val`` | boxes composited into 7-Scenes frames 150-299, seed 1 |
| val | ``static_val_every<k>`` | 7-Scenes frames 150-299 at every k-th frame |
| val | ``tum_walking`` | the TUM fr3 walking clip: two people, TUM's ground truth (kept apart in the data root's ``ground_truth/``) |
| fresh | ``comp_<scenario>_fresh``, ``synth_<scenario>_fresh`` | the composites on frames 150-299 and the synthetic scenes at seed 3: run once, after the last change, to check the validation split was not tuned on by looking at it |
| draws | ``comp_<scenario>_draw<k>`` | the composites on frames 150-299 at five more draws of their boxes (seeds 4-8): one composite is one draw of its boxes' textures, paths and sensor noise, and a setting's effect on it can be the draw's (``bench/compare_draws.py`` pools them) |

The composites' scenarios are the failure cases of issue 18: three boxes covering about half
the view (``three_boxes``), boxes entering and leaving the view (``enter_leave``), a box
that stops and starts again (``stop_start``), and the two earlier ones (``handheld_slow``,
``fixed_camera_2``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

from _common import SEVEN_SCENES, TUM_WALKING, tum_walking_truth, with_groundtruth

from jaxvo.host.readers.io import InMemorySequence, data_root, open_sequence
from jaxvo.synth.scenes import composite_sequence, make_sequence

SYNTHETIC = ("fixed_camera_1", "fixed_camera_2", "handheld_fast", "handheld_slow",
             "close_approach", "static")
COMPOSITES = ("three_boxes", "enter_leave", "stop_start", "handheld_slow", "fixed_camera_2")
HALF = 150  # 7-Scenes frames per split
DRAWS = (4, 5, 6, 7, 8)  # the composites' seeds of the draws split (0 dev, 1 val, 3 fresh)
MAIN = ("dev", "val", "fresh")  # what a script's "--split all" runs: the draws only by name


class Case(NamedTuple):
    name: str
    split: str  # "dev" or "val"
    kind: str  # "synthetic", "composite", "static", "people"
    source: str | None  # real folder it reads under the data root, None for synthetic
    build: Callable[[], InMemorySequence]


def static_case(start: int, step: int, length: int = HALF):
    """A builder of the 7-Scenes frames ``start`` .. ``start + length - 1`` at every
    ``step``-th frame."""
    def build():
        seq = InMemorySequence(open_sequence(data_root() / SEVEN_SCENES), start=start,
                               frames=-(-length // step), step=step)
        seq.name = f"{SEVEN_SCENES}_{start:04d}_{start + length - 1:04d}_every{step}"
        return seq
    return build


def _composite(scenario: str, start: int, seed: int):
    return lambda: InMemorySequence(composite_sequence(
        data_root() / SEVEN_SCENES, scenario, start=start, frames=HALF, seed=seed))


def cases() -> list[Case]:
    """Every case of both splits, development first."""
    out = [Case(f"synth_{s}", "dev", "synthetic", None,
                lambda s=s: InMemorySequence(make_sequence(s, frames=90, seed=0)))
           for s in SYNTHETIC]
    for split, start, seed in (("dev", 0, 0), ("val", HALF, 1)):
        out += [Case(f"comp_{s}_{split}", split, "composite", SEVEN_SCENES,
                     _composite(s, start, seed)) for s in COMPOSITES]
        out += [Case(f"static_{split}_every{k}", split, "static", SEVEN_SCENES, static_case(start, k))
                for k in (1, 2, 4)]
    out.append(Case("tum_walking", "val", "people", TUM_WALKING, lambda: with_groundtruth(
        InMemorySequence(open_sequence(data_root() / TUM_WALKING)), tum_walking_truth())))
    out += [Case(f"comp_{s}_fresh", "fresh", "composite", SEVEN_SCENES, _composite(s, HALF, 3))
            for s in COMPOSITES]
    out += [Case(f"synth_{s}_fresh", "fresh", "synthetic", None,
                 lambda s=s: InMemorySequence(make_sequence(s, frames=90, seed=3)))
            for s in SYNTHETIC]
    out += [Case(f"comp_{s}_draw{k}", "draws", "composite", SEVEN_SCENES, _composite(s, HALF, k))
            for s in COMPOSITES for k in DRAWS]
    return out


def in_split(case: Case, split: str) -> bool:
    """Whether ``case`` belongs to ``split``, ``"all"`` meaning every split of ``MAIN``."""
    return case.split == split or (split == "all" and case.split in MAIN)


def available(case: Case) -> str | None:
    """None when the case can run here, else why not."""
    if case.source is None:
        return None
    path = data_root() / case.source
    if not (path / "associations.txt").is_file() and not (path / "rgb.txt").is_file():
        return f"{case.source} not found at {path} (set JAXVO_DATA to the shared data folder)"
    return None


def runnable(todo: list[Case]) -> tuple[list[Case], dict[str, str]]:
    """The cases of ``todo`` that can run here, and why each of the others cannot."""
    skipped = {c.name: why for c in todo if (why := available(c))}
    return [c for c in todo if c.name not in skipped], skipped
