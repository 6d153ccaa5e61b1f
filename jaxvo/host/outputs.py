"""Where a command writes (host side): outputs checked before any work, so nothing a
command reads is ever written over and nothing is found unwritable half-way; images
written so that a failure names the file."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from jaxvo.errors import InputError


def check_outputs(reads, *, files: dict[str, Path] | None = None,
                  folders: dict[str, Path] | None = None) -> None:
    """Refuse outputs that would overwrite what a command reads, or each other.

    Checked before any work, with paths resolved (symbolic links followed): no output file
    is a file the command reads or another output file; no output folder (where the command
    names the files it writes: masks by timestamp, a study's tables) holds a file the
    command reads, is another output folder, or holds an output file.

    Args:
      reads: the files (and folders) the command reads.
      files: option -> output file (e.g. ``{"--out": Path("traj.txt")}``).
      folders: option -> output folder (e.g. ``{"--masks": Path("masks")}``).
    Raises:
      InputError: one line naming the options, the paths and the clash.
    """
    files, folders = dict(files or {}), dict(folders or {})
    read = {Path(os.path.realpath(p)): Path(p) for p in reads}
    parents = {}
    for real, given in read.items():
        parents.setdefault(real.parent, given)
    seen_files: dict[Path, str] = {}
    for what, p in files.items():
        real = Path(os.path.realpath(p))
        if real in read:
            raise InputError(f"{what} {p} would overwrite the input {read[real]}")
        if real in seen_files:
            raise InputError(f"{what} and {seen_files[real]} are the same file {p}; each "
                             "output needs its own")
        seen_files[real] = what
    seen_folders: dict[Path, str] = {}
    for what, p in folders.items():
        real = Path(os.path.realpath(p))
        if real in read or real in parents:
            held = parents.get(real, read.get(real))
            raise InputError(f"{what} {p} holds {held}, which this command reads; writing "
                             "there could overwrite it: choose another folder")
        if real in seen_folders:
            raise InputError(f"{what} and {seen_folders[real]} are the same folder {p}; each "
                             "output needs its own")
        seen_folders[real] = what
    for real, what in seen_files.items():
        if real.parent in seen_folders:
            other = seen_folders[real.parent]
            raise InputError(f"{what} {files[what]} lies in the folder of {other}, which "
                             f"{other} writes into; put it elsewhere")


def output_file(path: str | Path, *, what: str) -> Path:
    """``path`` as a file this run can write, checked before any work is done (what it must
    not overwrite: :func:`check_outputs`).

    Args:
      path: the file (it may exist; it is not changed here).
      what: how to name it in a message (e.g. ``--out``).
    Returns:
      the path.
    Raises:
      InputError: the path is a folder, its folder does not exist, or it cannot be written.
    """
    p = Path(path)
    if p.is_dir():
        raise InputError(f"{what} {p}: is a folder, not a file")
    if not p.parent.is_dir():
        raise InputError(f"{what} {p}: folder {p.parent} does not exist")
    existed = p.exists()
    try:
        with open(p, "a"):  # "a": an existing file stays as it is
            pass
    except OSError as exc:
        raise InputError(f"{what} {p}: cannot write ({exc.strerror})") from None
    if not existed:
        p.unlink()
    return p


def output_folder(path: str | Path, *, what: str, empty: bool = False) -> Path:
    """``path`` as a folder this run can write into, created if missing.

    Args:
      path: the folder.
      what: how to name it in a message (e.g. ``--masks``).
      empty: refuse a folder that already holds anything (a command that writes a whole
        folder, whose old files would be left mixed with the new ones or overwritten).
    Returns:
      the path.
    Raises:
      InputError: it exists and is not a folder (or, with ``empty``, is not empty), or
        cannot be created or written into.
    """
    import tempfile

    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InputError(f"{what} {p}: exists and is not a folder")
    if empty and p.is_dir() and any(p.iterdir()):
        raise InputError(f"{what} {p}: the folder is not empty; give a new or empty folder "
                         "(nothing in it is changed)")
    try:
        p.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=p).close()
    except OSError as exc:
        raise InputError(f"{what} {p}: cannot write there ({exc.strerror})") from None
    return p


def write_image(path: str | Path, image: np.ndarray) -> None:
    """Write an image as ``cv2.imwrite`` does, but raise ``OSError`` naming the file and the
    cause when it cannot be written (OpenCV only returns False, and on a full disk libpng
    prints ``libpng error: Write Error`` on its own line): encoded in memory by OpenCV,
    written by Python.

    Args:
      path: the file; its extension picks the format (``.png``).
      image: (H, W) or (H, W, 3) array as OpenCV writes it.
    """
    import cv2

    ok, data = cv2.imencode(Path(path).suffix or ".png", image)
    if not ok:
        raise OSError(f"{path}: OpenCV could not encode the image")
    try:
        with open(path, "wb") as fh:
            fh.write(data)
    except OSError as exc:  # write() and close() errors name no file of their own
        raise OSError(exc.errno, exc.strerror, str(path)) from None
