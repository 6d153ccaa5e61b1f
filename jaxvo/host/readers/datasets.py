"""Getting the benchmarks: the TUM RGB-D and Bonn RGB-D Dynamic sequences by name, downloaded
(resumed with HTTP ranges, checked) and unpacked safely into the layout ``jaxvo run`` reads.

The catalogue follows the publishers' own naming: TUM's
``https://cvg.cit.tum.de/rgbd/dataset/freiburg3/rgbd_dataset_freiburg3_walking_xyz.tgz``
(also as a ROS 1 ``.bag``), named here ``fr3/walking_xyz``; Bonn's
``https://www.ipb.uni-bonn.de/html/projects/rgbd_dynamic2019/rgbd_bonn_balloon.zip``, named
``balloon``. Each archive unpacks to one folder of the same name (``rgb.txt``,
``depth.txt``, ``groundtruth.txt``, ``rgb/``, ``depth/``), whose name gives ``jaxvo run`` its
camera preset. Neither publisher gives checksums: the size is checked against the server's
``Content-Length`` / ``Content-Range``, the archive's own CRCs when it is unpacked, and a
SHA-256 where the caller has one.
"""

from __future__ import annotations

import gzip
import hashlib
import http.client
import re
import shutil
import stat
import tarfile
import urllib.error
import urllib.request
import zipfile
from pathlib import Path, PurePosixPath
from typing import NamedTuple

from jaxvo.errors import InputError

TUM_URL = "https://cvg.cit.tum.de/rgbd/dataset/"
BONN_URL = "https://www.ipb.uni-bonn.de/html/projects/rgbd_dynamic2019/"

# TUM RGB-D (Sturm et al., IROS 2012): the sequences with public ground truth, by camera
TUM_SEQUENCES = {
    1: ("xyz", "rpy", "360", "floor", "desk", "desk2", "room", "plant", "teddy"),
    2: ("xyz", "rpy", "360_hemisphere", "360_kidnap", "desk", "desk_with_person",
        "large_no_loop", "large_with_loop", "pioneer_360", "pioneer_slam", "pioneer_slam2",
        "pioneer_slam3", "coke", "dishes", "flowerbouquet", "flowerbouquet_brownbackground",
        "metallic_sphere", "metallic_sphere2"),
    3: ("long_office_household", "nostructure_notexture_far",
        "nostructure_notexture_near_withloop", "nostructure_texture_far",
        "nostructure_texture_near_withloop", "structure_notexture_far",
        "structure_notexture_near", "structure_texture_far", "structure_texture_near",
        "sitting_static", "sitting_xyz", "sitting_halfsphere", "sitting_rpy", "walking_static",
        "walking_xyz", "walking_halfsphere", "walking_rpy", "cabinet", "large_cabinet", "teddy"),
}
# Bonn RGB-D Dynamic (Palazzolo et al., IROS 2019)
BONN_SEQUENCES = (
    "balloon", "balloon2", "balloon_tracking", "balloon_tracking2", "crowd", "crowd2",
    "crowd3", "kidnapping_box", "kidnapping_box2", "moving_nonobstructing_box",
    "moving_nonobstructing_box2", "moving_obstructing_box", "moving_obstructing_box2",
    "person_tracking", "person_tracking2", "placing_nonobstructing_box",
    "placing_nonobstructing_box2", "placing_nonobstructing_box3", "placing_obstructing_box",
    "removing_nonobstructing_box", "removing_nonobstructing_box2", "removing_obstructing_box",
    "static", "static_close_far", "synchronous", "synchronous2",
)
DATASETS = ("tum", "bonn")
_CHUNK = 1 << 20  # bytes read and written at a time


class Entry(NamedTuple):
    """One downloadable sequence."""

    dataset: str  # "tum" or "bonn"
    name: str  # as the catalogue names it: "fr3/walking_xyz", "balloon"
    folder: str  # the folder it unpacks to: "rgbd_dataset_freiburg3_walking_xyz"
    url: str  # the archive (or bag) as published


def catalogue(dataset: str) -> list[Entry]:
    """Every sequence of ``dataset`` (``"tum"`` or ``"bonn"``), archives as published."""
    if dataset == "tum":
        return [Entry("tum", f"fr{k}/{n}", f"rgbd_dataset_freiburg{k}_{n}",
                      f"{TUM_URL}freiburg{k}/rgbd_dataset_freiburg{k}_{n}.tgz")
                for k, names in TUM_SEQUENCES.items() for n in names]
    if dataset == "bonn":
        return [Entry("bonn", n, f"rgbd_bonn_{n}", f"{BONN_URL}rgbd_bonn_{n}.zip")
                for n in BONN_SEQUENCES]
    raise InputError(f"unknown dataset {dataset!r}: {' or '.join(DATASETS)}")


def find(dataset: str, name: str, *, bag: bool = False, mirror: str | None = None) -> Entry:
    """The catalogue entry of ``name`` (also accepted: the folder name, or TUM's
    ``freiburg3/...``), its URL the ROS 1 bag with ``bag`` (TUM only) and on ``mirror``
    (a base URL the file name is appended to) when given.

    Raises:
      InputError: an unknown name (the message suggests close ones), a bag of Bonn, or a
        mirror that is not an http(s) URL.
    """
    import difflib

    entries = catalogue(dataset)
    key = re.sub(r"^freiburg(\d)", r"fr\1", name.strip().strip("/"))
    found = [e for e in entries if key in (e.name, e.folder)]
    if not found:
        near = difflib.get_close_matches(key, [e.name for e in entries], n=3)
        hint = f"; did you mean {', '.join(near)}?" if near else ""
        raise InputError(f"no {dataset} sequence {name!r}{hint} (jaxvo data list {dataset})")
    entry = found[0]
    if bag:
        if dataset != "tum":
            raise InputError("--bag: only TUM publishes its sequences as ROS bags")
        entry = entry._replace(url=entry.url.removesuffix(".tgz") + ".bag")
    if mirror is not None:
        if not re.match(r"^https?://", mirror):
            raise InputError(f"--mirror must be an http:// or https:// URL, got {mirror!r}")
        entry = entry._replace(url=mirror.rstrip("/") + "/" + entry.url.rsplit("/", 1)[1])
    return entry


def _total(resp, start: int) -> int | None:
    """The whole file's size from a response to a request from byte ``start``, or None."""
    rng = resp.headers.get("Content-Range")
    if rng and "/" in rng and rng.rsplit("/", 1)[1].strip().isdigit():
        return int(rng.rsplit("/", 1)[1])
    length = resp.headers.get("Content-Length")
    return start + int(length) if length and length.isdigit() else None


def download(url: str, dest: Path, *, progress=None, timeout: float = 30.0) -> Path:
    """Download ``url`` to ``dest``, resuming a ``dest.part`` left by an earlier try.

    A partial file is continued with an HTTP ``Range`` request; a server that answers the
    whole file (200) starts it again. The size is checked against the server's; a
    connection that breaks leaves the part for the next call to resume.

    Args:
      url: http(s) URL.
      dest: the file to write (its folder exists).
      progress: ``callable(done, total)`` in KiB, or None.
      timeout: seconds to wait for the server on each read.
    Returns:
      ``dest``.
    Raises:
      InputError: the server refused, the connection broke (the part is kept), or the size
        differs from the server's.
    """
    part = dest.with_name(dest.name + ".part")
    have = part.stat().st_size if part.exists() else 0
    req = urllib.request.Request(url, headers={"Range": f"bytes={have}-"} if have else {})
    try:
        resp = urllib.request.urlopen(req, timeout=timeout)
    except urllib.error.HTTPError as exc:
        if exc.code == 416 and have:  # nothing left past what we have: complete
            part.replace(dest)
            return dest
        raise InputError(f"{url}: the server answered {exc.code} {exc.reason}") from None
    except (urllib.error.URLError, OSError) as exc:
        reason = getattr(exc, "reason", exc)
        raise InputError(f"{url}: cannot connect ({reason})") from None
    with resp:
        if resp.status != 206:  # the whole file: start again
            have = 0
        total = _total(resp, have)
        done = have
        try:
            fh = open(part, "ab" if have else "wb")  # noqa: SIM115 (closed below)
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror, str(part)) from None
        with fh:
            while True:
                try:
                    chunk = resp.read(_CHUNK)
                except (OSError, http.client.HTTPException) as exc:  # e.g. IncompleteRead
                    raise InputError(f"{url}: the download stopped after {done} of {total} "
                                     f"bytes ({exc}); run the same command again to resume"
                                     ) from None
                if not chunk:
                    break
                try:  # a full disk: the file and the cause, not the network's advice
                    fh.write(chunk)
                    fh.flush()
                except OSError as exc:
                    raise OSError(exc.errno, exc.strerror, str(part)) from None
                done += len(chunk)
                if progress is not None:
                    progress(done >> 10, None if total is None else total >> 10)
    if total is not None and done != total:
        raise InputError(f"{url}: the download stopped after {done} of {total} bytes; run "
                         "the same command again to resume")
    part.replace(dest)
    return dest


def check_sha256(path: Path, expected: str) -> None:
    """Raise :class:`InputError` (and remove ``path``) when its SHA-256 is not ``expected``."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(_CHUNK):
            h.update(chunk)
    if h.hexdigest() != expected.lower():
        path.unlink()
        raise InputError(f"{path.name}: SHA-256 {h.hexdigest()}, not {expected.lower()}; "
                         "removed: run the command again to download it anew")


def _safe_name(name: str, archive: Path) -> PurePosixPath:
    """A member's path, refused when it is absolute or climbs out (``..``)."""
    p = PurePosixPath(name.replace("\\", "/"))
    if p.is_absolute() or ".." in p.parts or not p.parts or re.match(r"^[A-Za-z]:", name):
        raise InputError(f"{archive}: member {name!r} would land outside the folder; "
                         "nothing unpacked")
    return p


def _entries(archive: Path):
    """Yield ``(path, is_dir, fileobj)`` for each member of a zip or tar(.gz), in one pass,
    each checked as it comes (:func:`_safe_name`); links, devices and other special members
    are refused."""
    if zipfile.is_zipfile(archive):
        with zipfile.ZipFile(archive) as z:
            for info in z.infolist():
                path = _safe_name(info.filename, archive)
                if stat.S_ISLNK(info.external_attr >> 16):
                    raise InputError(f"{archive}: member {info.filename!r} is a link; nothing "
                                     "unpacked")
                yield path, info.is_dir(), None if info.is_dir() else z.open(info)
        return
    with open(archive, "rb") as fh:
        gzipped = fh.read(2) == b"\x1f\x8b"
    # gzip's own reader checks the CRC at the end of the stream (tarfile's does not), and
    # tarfile streams through it ("r|"): a .tgz is decompressed once
    raw = gzip.open(archive) if gzipped else open(archive, "rb")  # noqa: SIM115 (with below)
    with raw:
        try:
            with tarfile.open(fileobj=raw, mode="r|") as t:
                for m in t:
                    path = _safe_name(m.name, archive)
                    if not (m.isfile() or m.isdir()):
                        raise InputError(f"{archive}: member {m.name!r} is a link or device; "
                                         "nothing unpacked")
                    yield path, m.isdir(), t.extractfile(m) if m.isfile() else None
        except tarfile.TarError as exc:
            raise InputError(f"{archive}: cannot read it as a zip or tar archive ({exc})"
                             ) from None
        while raw.read(_CHUNK):  # past tar's end marker to gzip's end, where it checks
            pass


def unpack(archive: Path, dest: Path, *, require: str | None = None) -> list[Path]:
    """Unpack a zip or tar(.gz) ``archive`` into folder ``dest``, safely: no member with an
    absolute path or ``..``, no links or devices, files written by us (never by the
    archive's own extraction) into a staging folder that is moved into place only when
    whole, so a refused member or an interrupted unpack leaves nothing behind.

    Args:
      archive: the archive.
      dest: the folder to unpack into (exists).
      require: a path the archive must hold (``FOLDER/rgb.txt``); then only its top-level
        folder is moved into ``dest``, and an archive without it moves nothing (a
        sequence's ``rgb/``, ``depth/`` and lists at the top would land in ``dest`` itself).
    Returns:
      the top-level paths it created in ``dest``.
    Raises:
      InputError: an unsafe member, a corrupt archive (its CRC), an archive without
        ``require``, or a top-level entry that already exists in ``dest``.
    """
    staging = dest / f".{archive.name}.unpacking"
    shutil.rmtree(staging, ignore_errors=True)
    try:
        staging.mkdir()
        for path, is_dir, src in _entries(archive):
            target = staging.joinpath(*path.parts)
            if is_dir:
                target.mkdir(parents=True, exist_ok=True)
                continue
            target.parent.mkdir(parents=True, exist_ok=True)
            with src:
                _copy(src, target)
        tops = sorted(p.name for p in staging.iterdir())
        if require is not None:
            if not staging.joinpath(*Path(require).parts).is_file():
                held = ", ".join(tops[:6]) + (", ..." if len(tops) > 6 else "") or "nothing"
                raise InputError(f"{archive}: holds no {require} (its top level: {held}); "
                                 f"nothing unpacked into {dest}")
            tops = [Path(require).parts[0]]
        for top in tops:
            if (dest / top).exists():
                raise InputError(f"{dest / top} exists already; remove it or choose --dir")
        for top in tops:
            (staging / top).replace(dest / top)
    except OSError as exc:
        if exc.errno is not None:  # the system's (a full disk): said with the file, as it is
            raise
        raise InputError(f"{archive}: cannot unpack ({exc}); remove it and download it "
                         "again") from None  # gzip's: not a gzip file, a CRC that fails
    except (zipfile.BadZipFile, tarfile.TarError, EOFError) as exc:
        raise InputError(f"{archive}: cannot unpack ({exc}); remove it and download it "
                         "again") from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return [dest / top for top in tops]


def _copy(src, target: Path) -> None:
    """A member's bytes into ``target``; a write error (a full disk) names the file."""
    try:
        dst = open(target, "wb")  # noqa: SIM115 (closed below)
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror, str(target)) from None
    try:
        with dst:
            while chunk := src.read(_CHUNK):
                dst.write(chunk)
    except OSError as exc:
        if exc.errno is None:  # the archive's (gzip: a CRC that fails)
            raise
        raise OSError(exc.errno, exc.strerror, str(target)) from None
