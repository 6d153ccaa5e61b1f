"""Inputs a command names that are not there, said before NumPy loads.

The readers say the same when they open what is there (:func:`jaxvo.host.readers.io.
open_sequence`, :func:`jaxvo.trajectory.read_trajectory`), but their modules load NumPy
first; a command calls these at the start of its ``prepare`` so that a mistyped path is
answered at once, in the reader's words (tests/test_startup.py holds the two to one
wording).
"""

from __future__ import annotations

import os
from pathlib import Path

from jaxvo.errors import InputError


def require_sequence(path: str | Path) -> None:
    """Refuse a sequence (a folder, or a bag) that does not exist, in the words of
    ``open_sequence``; what is there is the reader's to judge."""
    if not os.path.exists(path):
        raise InputError(f"sequence folder not found: {Path(path)}")


def require_trajectory(path: str | Path) -> None:
    """Refuse a trajectory file that does not exist or is a folder, in the words of
    ``read_trajectory``; ``-`` (standard input) is the reader's to judge."""
    if str(path) == "-":
        return
    p = Path(path)
    if not p.exists():
        raise InputError(f"file not found: {p}")
    if p.is_dir():
        raise InputError(f"not a file: {p}")
