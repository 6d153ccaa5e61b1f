"""``jaxvo data list`` / ``jaxvo data get tum fr3/walking_xyz``: the benchmarks by name.

``get`` downloads the publisher's archive with a progress line (resuming a download that
stopped, checking its size and, with ``--sha256``, its checksum), unpacks it safely into
``--dir`` in the layout ``jaxvo run`` reads, and prints the command to run next
(:mod:`jaxvo.host.readers.datasets`).
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

EPILOG = """\
examples:
  jaxvo data list tum
  jaxvo data get tum fr3/walking_xyz --dir data/
  jaxvo data get bonn balloon --dir data/
  jaxvo data get tum fr3/walking_xyz --bag        # the ROS 1 bag instead (jaxvo run X.bag)

A download that stops (network, Ctrl-C) leaves FILE.part; the same command resumes it.
Neither publisher gives checksums: the size is checked against the server's, the archive's
CRCs while unpacking, and --sha256 where you have one."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.epilog = EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    sub = p.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True
    ls = sub.add_parser("list", help="the sequences by name",
                        description="The sequences jaxvo data get knows, by name.")
    ls.add_argument("dataset", nargs="?", metavar="DATASET", help="tum or bonn (default both)")
    get = sub.add_parser("get", help="download and unpack a sequence",
                         description="Download a sequence, check it, unpack it into --dir "
                         "and print the jaxvo run command for it.")
    get.add_argument("dataset", metavar="DATASET", help="tum (TUM RGB-D) or bonn (Bonn RGB-D "
                     "Dynamic)")
    get.add_argument("name", metavar="NAME", help="e.g. fr3/walking_xyz, balloon "
                     "(jaxvo data list)")
    get.add_argument("--dir", default=".", metavar="DIR",
                     help="folder to unpack into (default the current one)")
    get.add_argument("--bag", action="store_true",
                     help="the ROS 1 bag instead of the archive (TUM only; not unpacked)")
    get.add_argument("--mirror", metavar="URL",
                     help="download from this base URL instead of the publisher's (the "
                     "archive's file name is appended)")
    get.add_argument("--sha256", metavar="HEX", help="check the download's SHA-256")
    get.add_argument("--keep-archive", action="store_true",
                     help="keep the archive after unpacking it")
    get.add_argument("--quiet", "-q", action="store_true",
                     help="no progress (what is downloaded, and how far)")


def run(args: argparse.Namespace) -> int:
    from jaxvo.errors import InputError
    from jaxvo.host.readers.datasets import DATASETS, catalogue

    if args.dataset is not None and args.dataset not in DATASETS:
        raise InputError(f"unknown dataset {args.dataset!r}: {' or '.join(DATASETS)}")
    if args.action == "list":
        for dataset in [args.dataset] if args.dataset else DATASETS:
            for e in catalogue(dataset):
                print(f"{e.dataset:<5} {e.name:<42} {e.folder}")
        return 0
    return _get(args)


def _entry(args: argparse.Namespace):
    """The catalogue's entry for the sequence asked for, and --sha256 checked: answered
    before NumPy loads (the catalogue needs none, and neither does --dir's check after)."""
    from jaxvo.errors import InputError
    from jaxvo.host.readers.datasets import find

    entry = find(args.dataset, args.name, bag=args.bag, mirror=args.mirror)
    if args.sha256 is not None and not re.fullmatch(r"[0-9a-fA-F]{64}", args.sha256):
        raise InputError(f"--sha256 must be 64 hexadecimal digits, got {args.sha256!r}")
    return entry


def _get(args: argparse.Namespace) -> int:
    entry = _entry(args)
    from jaxvo.host.readers.datasets import check_sha256, download, unpack
    from jaxvo.host.services.progress import Progress
    from jaxvo.host.writers.outputs import output_folder

    dest = output_folder(args.dir, what="--dir")
    target = dest / (entry.url.rsplit("/", 1)[1] if args.bag else entry.folder)
    out = entry.name.replace("/", "_") + ".txt"
    if target.exists() and (args.bag or (target / "rgb.txt").is_file()):
        print(f"{target} is there already")
        print(f"next: jaxvo run {target} --out {out}")
        return 0
    archive = dest / entry.url.rsplit("/", 1)[1]
    if not archive.exists():
        progress = Progress(f"download {entry.name}", None, unit="KiB", enabled=not args.quiet)
        if not args.quiet:
            print(f"downloading {entry.url}", file=sys.stderr)
        download(entry.url, archive, progress=progress)
        progress.close()
    if args.sha256 is not None:
        check_sha256(archive, args.sha256)
    if not args.bag:
        unpack(archive, dest, require=f"{entry.folder}/rgb.txt")
        if not args.keep_archive:
            archive.unlink()
    size = _size(target)
    print(f"{entry.dataset} {entry.name}: {target} ({size / 2**20:.1f} MiB)")
    print(f"next: jaxvo run {target} --out {out}")
    return 0


def _size(path: Path) -> int:
    """Bytes in a file, or in every file under a folder."""
    if path.is_file():
        return path.stat().st_size
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
