"""Why a frame was skipped: one integer code per frame, shared by every stage.

Traced code cannot raise, so each stage returns a code instead (0 = fine) and the
pipeline carries the pose over a frame whose code is not OK (thesis Fig. 1.2: a failing
stage skips the current RGB-D image).
"""

from __future__ import annotations

import enum


class Status(enum.IntEnum):
    OK = 0
    TOO_FEW_FLOW = 1  # fewer valid grid flow vectors than a minimal sample needs
    NO_HYPOTHESIS = 2  # no minimal sample passed its own rigidity check
    NO_SEGMENT = 3  # no cluster kept N_threshold inliers
    NO_STATIC = 4  # too few points carry the static identifier
    EGO_DEGENERATE = 5  # static points degenerate (collinear / coincident)
    BAD_INPUT = 6  # frame unreadable or of the wrong size (set on the host)
    NO_BACKGROUND = 7  # every motion in view lies in front of the background: none of it in view

    @property
    def reason(self) -> str:
        return _REASONS[self]


_REASONS = {
    Status.OK: "ok",
    Status.TOO_FEW_FLOW: "too few valid flow vectors (textureless, blurred or no depth)",
    Status.NO_HYPOTHESIS: "no rigid motion hypothesis could be verified",
    Status.NO_SEGMENT: "no motion segment reached the minimum size",
    Status.NO_STATIC: "too few points labelled static background",
    Status.EGO_DEGENERATE: "static points are degenerate for a rigid fit",
    Status.BAD_INPUT: "frame unreadable or of the wrong size",
    Status.NO_BACKGROUND: "no background in view (every motion in view lies in front of it)",
}


def first_failure(*codes):
    """The first non-OK code among ``codes`` (traced integers), else OK."""
    import jax.numpy as jnp

    out = jnp.int32(Status.OK)
    for code in reversed(codes):
        out = jnp.where(code != Status.OK, jnp.int32(code), out)
    return out
