"""Where a command writes (host side): every output checked before any work, and written
whole or not at all.

Three questions, each answered once here for every writer of jaxvo (the CLI's commands, the
Rerun recording, the study's tables, the evo zips, a synthetic sequence):

* May this path be written? :func:`check_outputs` refuses, before any work, an output that
  is a file the command reads (compared by device and inode, so hard and symbolic links are
  caught; a folder the command reads protects every file under it), another output, or a
  folder that holds what the command reads; :func:`output_file` and :func:`output_folder`
  check that each can be written, and say what standard output (``-``) means for it.
* How is it written? :class:`OutputFile`: into a temporary file beside the target, renamed
  over it (``os.replace``) once whole. A reader never sees half a file; an interrupted or
  failed command leaves the earlier file, or none, never a cut one; two commands writing
  one output at once each leave a whole file (the one that finishes last is kept, and
  :func:`output_file` warns that another is writing it). A target that is no regular file
  (``/dev/null``, a FIFO, a terminal) is written as the stream it is.
* What does a failure say? Every write, flush, close and rename of an :class:`OutputFile`
  that fails raises ``OSError`` naming the target (a full disk fails in ``write`` or
  ``close``, which name no file of their own); the CLI prints it as one line.

A folder of outputs (masks and overlays, named by frame; a study's tables) is whole file
by file: each file in it appears whole or not at all, and an interrupted command keeps the
files it finished. A folder that is one output (a synthetic sequence, a ROS 2 bag) is whole
as a folder: an :class:`OutputFolder`. A writer of a new kind of output uses the same three
steps: ``output_file`` / ``output_folder`` and ``check_outputs`` before any work, then an
:class:`OutputFile` per file or an :class:`OutputFolder` (for a library that writes a path
itself, :attr:`OutputFile.temporary` as Rerun's file sink takes it, or an
``OutputFolder(..., make_folder=False)`` as ``rosbags``' bag writer takes it)::

    out = output_file(args.out, what="--out")          # before any work
    check_outputs(seq.files(), files={"--out": out})
    ...
    with OutputFile(out, what="--out") as fh:          # whole or not at all
        fh.write(data)
"""

from __future__ import annotations

import atexit
import contextlib
import errno
import os
import secrets
import stat
import sys
import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Self

from jaxvo.errors import InputError

if TYPE_CHECKING:  # the commands check their outputs before NumPy loads: kept light
    import numpy as np

# the file name that means standard output, as command-line tools take it
STDOUT = "-"

# a temporary output is named ".<target>.jaxvo-<pid>-<random>.part" beside its target: hidden,
# and the pid tells whether the process writing it still runs (a leftover of a killed one is
# removed by the next command that writes the target)
_PART = ".part"
_TAG = ".jaxvo-"
# the target's name is cut to this many characters in the temporary name (file names are at
# most 255 bytes)
_NAME_KEEP = 180


class OutputWarning(UserWarning):
    """Something about an output the user should know, that does not stop the command
    (another process writes the same file; files of an earlier run left in a folder)."""


# --- what a path is ----------------------------------------------------------------------


def file_id(path: str | Path) -> tuple[int, int] | None:
    """``(device, inode)`` of the file ``path`` names (links followed), None if there is none."""
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return st.st_dev, st.st_ino


def _stream_ids() -> dict[tuple[int, int], str]:
    """The files this process's standard output and error are, by ``(device, inode)``, but
    the null device (writing there is harmless from any number of places)."""
    null = file_id(os.devnull)
    ids = {}
    for fd, name in ((2, "standard error"), (1, "standard output")):
        try:
            st = os.fstat(fd)
        except OSError:
            continue
        if (st.st_dev, st.st_ino) != null:
            ids[(st.st_dev, st.st_ino)] = name
    return ids


def stream_of(path: str | Path) -> str | None:
    """``"standard output"`` or ``"standard error"`` when ``path`` is the file this
    process's standard output or error already is (``/dev/stdout``, or the file ``>``
    redirected it to), else None."""
    key = file_id(path)
    return None if key is None else _stream_ids().get(key)


# set by the CLI when the command started with its standard output closed (``>&-``; the
# null device stands in for it, jaxvo.cli.main._standard_streams)
STDOUT_CLOSED = False


def stdout_open() -> bool:
    """Whether this process has a standard output to write to (``>&-`` closes it)."""
    try:
        os.fstat(1)
    except OSError:
        return False
    return sys.stdout is not None and not STDOUT_CLOSED


def _folder_ids(folder: Path) -> set[tuple[int, int]]:
    """The ids of the files directly in ``folder`` (links followed; not its subfolders')."""
    ids = set()
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return ids
    for entry in entries:
        key = file_id(entry.path)
        if key is not None and not entry.is_dir():
            ids.add(key)
    return ids


# --- checked before any work ------------------------------------------------------------


def check_outputs(reads, *, files: dict[str, Path] | None = None,
                  folders: dict[str, Path] | None = None) -> None:
    """Refuse outputs that would overwrite what a command reads, or each other.

    Checked before any work, by ``(device, inode)`` where the path exists (a hard link, a
    symbolic link, ``/dev/stdout`` or another spelling of an input is the input) and by
    resolved path where it does not yet: no output file is a file the command reads, a file
    under a folder it reads, or another output file; no output folder (where the command
    names the files it writes: masks by timestamp, a study's tables) is or holds a file the
    command reads, is another output folder, or holds an output file.

    Args:
      reads: the files the command reads, and folders whose every file it protects (a
        sequence's image folders: its other images too, e.g. of frames it does not read).
      files: option -> output file (e.g. ``{"--out": Path("traj.txt")}``); standard output
        (``"-"``) is no file and is left out.
      folders: option -> output folder (e.g. ``{"--masks": Path("masks")}``).
    Raises:
      InputError: one line naming the options, the paths and the clash.
    """
    files = {k: Path(v) for k, v in (files or {}).items() if str(v) != STDOUT}
    folders = {k: Path(v) for k, v in (folders or {}).items()}
    read_files: dict[object, Path] = {}  # id (or resolved path) -> the path as given
    read_folders: dict[object, Path] = {}  # a folder holding a read file -> that file
    for p in map(Path, reads):
        if p.is_dir():
            for key in _folder_ids(p):
                read_files.setdefault(key, p)
            read_folders.setdefault(_key(p), p)
            continue
        key = _key(p)
        read_files.setdefault(key, p)
        read_folders.setdefault(_key(p.parent), p)
    seen_files: dict[object, str] = {}
    for what, p in files.items():
        key = _key(p)
        if key in read_files:
            held = read_files[key]
            how = f"a file of the input folder {held}" if held.is_dir() else f"the input {held}"
            raise InputError(f"{what} {p} would overwrite {how}")
        if key in seen_files:
            raise InputError(f"{what} and {seen_files[key]} are the same file {p}; each "
                             "output needs its own")
        seen_files[key] = what
    seen_folders: dict[object, str] = {}
    for what, p in folders.items():
        key = _key(p)
        if key in read_folders or key in read_files:
            held = read_folders.get(key, read_files.get(key))
            raise InputError(f"{what} {p} holds {held}, which this command reads; writing "
                             "there could overwrite it: choose another folder")
        if key in seen_folders:
            raise InputError(f"{what} and {seen_folders[key]} are the same folder {p}; each "
                             "output needs its own")
        seen_folders[key] = what
    for what, p in files.items():
        parent = _key(p.parent)
        if parent in seen_folders:
            other = seen_folders[parent]
            raise InputError(f"{what} {p} lies in the folder of {other}, which "
                             f"{other} writes into; put it elsewhere")


def _key(p: Path) -> object:
    """What identifies a path: its ``(device, inode)`` where it exists, else its resolved
    path (two spellings of one new file are one file)."""
    key = file_id(p)
    return key if key is not None else os.path.realpath(p)


def stream_target(path: str | Path, *, what: str, stdout: bool = False) -> Path | str:
    """:data:`STDOUT` where ``path`` means standard output (``-``, or a path that is the
    file standard output already is, as ``--out /dev/stdout > f``: written once, not
    twice), else the path.

    Args:
      path: the output as given.
      what: how to name it in a message (e.g. ``--out``).
      stdout: the output may go to standard output.
    Raises:
      InputError: standard output where the output cannot go, or is closed; the file
        standard error is.
    """
    text = str(path)
    stream = "standard output" if text == STDOUT else stream_of(path)
    if stream == "standard output" and stdout:
        if not stdout_open():
            raise InputError(f"{what} {text}: standard output is closed; name a file")
        return STDOUT
    if stream is not None:
        why = (f"{what} writes a file, not standard output; name a file" if text == STDOUT
               else f"is this command's {stream}, where its "
               + ("summary goes" if stream == "standard output" else "messages go")
               + "; name another file" + (" (or - for standard output)" if stdout else ""))
        raise InputError(f"{what} {text}: {why}")
    return Path(path)


def file_target(path: str | Path, *, what: str, stdout: bool = False,
                folders: Iterable[str | Path] = ()) -> Path | str:
    """The checks of :func:`output_file` that nothing the command reads can answer
    otherwise (:func:`check_outputs` finds no input in a stream, a folder or a file whose
    folder is missing): a command asks them before it reads its inputs, and
    :func:`output_file` again in its place. Nothing is written.

    Args:
      path, what, stdout: as :func:`output_file`'s.
      folders: the command's output folders, made later: a file whose missing folder is
        one of them is left to :func:`check_outputs` (it lies in another output's folder).
    Returns:
      the path, or :data:`STDOUT` when it goes to standard output.
    Raises:
      InputError: standard output where it cannot go (:func:`stream_target`), a folder, or
        a missing folder.
    """
    if stream_target(path, what=what, stdout=stdout) == STDOUT:
        return STDOUT
    p = Path(path)
    if p.is_dir():
        raise InputError(f"{what} {p}: is a folder, not a file")
    if not p.parent.is_dir() and _key(p.parent) not in {_key(Path(f)) for f in folders}:
        raise InputError(f"{what} {p}: folder {p.parent} does not exist")
    return p


def folder_target(path: str | Path, *, what: str, empty: bool = False) -> Path:
    """The checks of :func:`output_folder` that create nothing: a command asks them before
    its checks that need NumPy, and :func:`output_folder` (which creates the folder) again
    in its place.

    Raises:
      InputError: it exists and is not a folder (or, with ``empty``, is not empty).
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InputError(f"{what} {p}: exists and is not a folder")
    if empty and p.is_dir() and any(p.iterdir()):
        raise InputError(f"{what} {p}: the folder is not empty; give a new or empty folder "
                         "(nothing in it is changed)")
    return p


def output_file(path: str | Path, *, what: str, stdout: bool = False) -> Path | str:
    """``path`` as a file this command can write, checked before any work is done (what it
    must not overwrite: :func:`check_outputs`).

    Args:
      path: the file (it may exist; it is not changed here); ``-`` is standard output.
      what: how to name it in a message (e.g. ``--out``).
      stdout: the output may go to standard output (:func:`stream_target`).
    Returns:
      the path, or :data:`STDOUT` when it goes to standard output.
    Raises:
      InputError: standard output where it cannot go (:func:`stream_target`), a folder, a
        missing folder, or a file that cannot be written.
    """
    p = file_target(path, what=what, stdout=stdout)
    if p == STDOUT:
        return STDOUT
    real = Path(os.path.realpath(p))
    if real.exists() and not _regular(real):
        if not os.access(real, os.W_OK):
            raise InputError(f"{what} {p}: cannot write (permission denied)")
        if stat.S_ISFIFO(os.stat(real).st_mode) and not _fifo_read(real):
            raise InputError(f"{what} {p}: a named pipe that no process reads (writing would "
                             "wait for one forever); start its reader first")
        return p  # a device or FIFO: written as the stream it is
    if real.exists() and not os.access(real, os.W_OK):
        raise InputError(f"{what} {p}: cannot write (the file is read-only)")
    try:
        OutputFile(p, what=what).discard()  # the folder takes a temporary file
    except OSError as exc:
        raise InputError(f"{what} {p}: cannot write ({exc.strerror})") from None
    _others_writing(real, what=f"{what} {p}")
    return p


def output_folder(path: str | Path, *, what: str, empty: bool = False,
                  names: set[str] | None = None) -> Path:
    """``path`` as a folder this command can write into, created if missing.

    A folder output is whole file by file (:class:`OutputFile` for each file): each file in
    it appears whole or not at all, and an interrupted command keeps those it finished.

    Args:
      path: the folder.
      what: how to name it in a message (e.g. ``--masks``).
      empty: refuse a folder that already holds anything (a command that writes a whole
        folder, whose old files would be left mixed with the new ones or overwritten).
      names: the file names this command may write there (e.g. the frames' masks); files of
        the same kind (suffix) already there and not among them are left as they are, with a
        warning that says so (an earlier run's masks of other frames, mixed with this run's).
    Returns:
      the path.
    Raises:
      InputError: it exists and is not a folder (or, with ``empty``, is not empty), or
        cannot be created or written into.
    """
    p = folder_target(path, what=what, empty=empty)
    try:
        p.mkdir(parents=True, exist_ok=True)
        OutputFile(p / "x", what=what).discard()
    except OSError as exc:
        raise InputError(f"{what} {p}: cannot write there ({exc.strerror})") from None
    if names is not None:
        suffixes = {Path(n).suffix for n in names}
        other = [f for f in os.listdir(p) if Path(f).suffix in suffixes and f not in names
                 and not f.startswith(".")]
        if other:
            warnings.warn(f"{what} {p}: holds {len(other)} file(s) this run does not write "
                          f"(e.g. {min(other)}, of an earlier run?); they are left as "
                          "they are, beside this run's", OutputWarning, stacklevel=2)
    return p


def _regular(p: Path) -> bool:
    try:
        return stat.S_ISREG(os.stat(p).st_mode)
    except OSError:
        return True  # missing: it will be a regular file


def _fifo_read(path: Path) -> bool:
    """Whether a process has the named pipe ``path`` open for reading (opening it to write
    would block until one does)."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_NONBLOCK)
    except OSError as exc:
        if exc.errno == errno.ENXIO:  # no reader
            return False
        raise
    os.close(fd)
    return True


def _others_writing(real: Path, *, what: str) -> None:
    """Remove the temporary files a killed jaxvo left beside ``real``; warn when a jaxvo
    still running writes it (the one that finishes last is kept, each whole)."""
    prefix = "." + real.name[:_NAME_KEEP] + _TAG
    try:
        names = [n for n in os.listdir(real.parent) if n.startswith(prefix) and
                 n.endswith(_PART)]
    except OSError:
        return
    for name in names:
        pid = name[len(prefix):].split("-", 1)[0]
        if not pid.isdigit() or int(pid) == os.getpid():
            continue
        if _alive(int(pid)):
            warnings.warn(f"{what}: another jaxvo (process {pid}) is writing it now; each "
                          "writes it whole, and the one that finishes last is kept",
                          OutputWarning, stacklevel=3)
        else:
            with contextlib.suppress(OSError):
                os.unlink(real.parent / name)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process
        return True
    return True


# --- written whole or not at all --------------------------------------------------------

# the outputs being written (OutputFile, OutputFolder), by id: what an abrupt end (a
# second Ctrl-C) settles
_PENDING: dict[int, object] = {}


class _WholeOrNothing:
    """What an output file and an output folder share: committed when a ``with`` block
    ends normally, discarded when an exception (also Ctrl-C) leaves it."""

    def commit(self) -> None:
        raise NotImplementedError

    def discard(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.discard()


class OutputFile(_WholeOrNothing):
    """One output file, written whole or not at all.

    The data goes to a temporary file beside the target (same folder, so the same file
    system; hidden, named after the target and this process); :meth:`commit` renames it over
    the target (``os.replace``, atomic), :meth:`discard` removes it. As a context manager it
    commits when the block ends normally and discards when an exception (also Ctrl-C) leaves
    it: the target then keeps its earlier content, or stays absent. A symbolic link as the
    target is followed (the file it points to is replaced, the link stays). A target that is
    a device, FIFO or terminal is written directly, as the stream it is.

    Every ``OSError`` of a write, flush, close or rename names the target as given.

    Example::

        with OutputFile("map.ply", what="--out") as fh:
            fh.write(header)
            fh.write(rows.tobytes())

    Args:
      path: the target.
      what: how to name it in messages (default: the path).
      text: open in text mode (else binary).
      keep_on_abort: what :func:`abort_pending` does with it when the process must end at
        once (a second Ctrl-C): commit it (a file whole at every :meth:`flush`, as a
        trajectory written line by line) or discard it (default).
      open_file: open the temporary file here; False leaves it to a library that writes a
        path itself (:attr:`temporary`), as Rerun's file sink.
    """

    def __init__(self, path: str | Path, *, what: str | None = None, text: bool = False,
                 keep_on_abort: bool = False, open_file: bool = True):
        self.path = Path(path)
        self.what = what or str(path)
        self.keep_on_abort = keep_on_abort
        self._done = False
        self._fh = None
        real = Path(os.path.realpath(self.path))
        self.target = real
        if not _regular(real):  # a device, FIFO or terminal: a stream, no rename
            self.temporary = None
            if open_file:
                self._fh = _Named(self._call(open, real, "w" if text else "wb"), str(self.path))
            return
        token = f"{os.getpid()}-{secrets.token_hex(4)}"
        self.temporary = real.parent / f".{real.name[:_NAME_KEEP]}{_TAG}{token}{_PART}"
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0)
        fd = self._call(os.open, self.temporary, flags, 0o666)  # the umask applies, as open()
        _PENDING[id(self)] = self
        with contextlib.suppress(OSError):  # a file replaced keeps its permissions
            os.chmod(fd, stat.S_IMODE(os.stat(real).st_mode))
        if open_file:
            self._fh = _Named(_open_fd(fd, text), str(self.path))
        else:
            os.close(fd)

    def _call(self, fn, *args):
        """``fn(*args)``, an ``OSError`` naming the target."""
        try:
            return fn(*args)
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror, str(self.path)) from None

    def write(self, data) -> None:
        """Write ``data`` (str in text mode, bytes-like else)."""
        self._call(self._fh.write, data)

    def flush(self) -> None:
        """Hand what was written to the operating system (an abrupt end after this keeps
        it, with ``keep_on_abort``)."""
        self._call(self._fh.flush)

    @property
    def handle(self):
        """The open file, for writers that take one (``zipfile``, ``savefig``,
        ``np.savez``); its errors name the target too."""
        return self._fh

    def commit(self) -> None:
        """Close, and put the file in place of the target (whole). Idempotent.

        Raises:
          OSError: naming the target (the temporary file is removed, the target kept).
        """
        if self._done:
            return
        self._done = True
        _PENDING.pop(id(self), None)
        try:
            if self._fh is not None:
                self._call(self._fh.close)
            if self.temporary is not None:
                self._call(os.replace, self.temporary, self.target)
        except BaseException:
            self._remove()
            raise

    def discard(self) -> None:
        """Close and remove the temporary file: the target stays as it was. Idempotent."""
        if self._done:
            return
        self._done = True
        _PENDING.pop(id(self), None)
        if self._fh is not None:
            with contextlib.suppress(OSError):
                self._fh.close()
        self._remove()

    def _remove(self) -> None:
        if self.temporary is not None:
            with contextlib.suppress(OSError):
                os.unlink(self.temporary)


class OutputFolder(_WholeOrNothing):
    """One output folder, written whole or not at all (a synthetic sequence, a ROS 2 bag).

    The files go into a temporary folder beside the target (:attr:`temporary`, hidden and
    named as :class:`OutputFile`'s); :meth:`commit` renames it onto the target, which must
    be missing or an empty folder (``os.replace``, atomic), and :meth:`discard` removes it.
    As a context manager it commits when the block ends normally and discards when an
    exception (also Ctrl-C) leaves it; a second Ctrl-C (:func:`abort_pending`) discards it
    too. A failure names the target.

    Example::

        with OutputFolder("seq", what="OUT_DIR") as folder:
            write_image(folder.temporary / "rgb" / "0.png", image)

    Args:
      path: the target folder (missing, or empty).
      what: how to name it in messages (default: the path).
      make_folder: create :attr:`temporary` here; False leaves it to a library that makes
        the folder at a path it is given and refuses one that exists (``rosbags``' bag
        writer, :mod:`jaxvo.host.writers.bagout`), as :class:`OutputFile`'s ``open_file`` leaves a
        file to Rerun. Such a library may name its files after the folder (a bag's
        ``NAME/NAME.mcap``), so :attr:`temporary` then carries the target's own name, inside
        a hidden holder folder beside the target that :meth:`commit` and :meth:`discard`
        remove.
    """

    keep_on_abort = False

    def __init__(self, path: str | Path, *, what: str | None = None, make_folder: bool = True):
        self.path = Path(path)
        self.what = what or str(path)
        self._done = False
        real = Path(os.path.realpath(self.path))
        self.target = real
        if real.exists() and not (real.is_dir() and not any(real.iterdir())):
            raise InputError(f"{self.what} {self.path}: exists and is not an empty folder")
        token = f"{os.getpid()}-{secrets.token_hex(4)}"
        # what is removed on discard: the temporary folder, or the holder around it
        self._holder = real.parent / f".{real.name[:_NAME_KEEP]}{_TAG}{token}{_PART}"
        self.temporary = self._holder if make_folder else self._holder / real.name
        try:
            os.mkdir(self._holder)
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror, str(self.path)) from None
        _PENDING[id(self)] = self

    def commit(self) -> None:
        """Put the folder in place of the target (whole). Idempotent.

        Raises:
          OSError: naming the target (the temporary folder is removed).
        """
        if self._done:
            return
        self._done = True
        _PENDING.pop(id(self), None)
        try:
            os.replace(self.temporary, self.target)
        except OSError as exc:
            self._remove()
            raise OSError(exc.errno, exc.strerror, str(self.path)) from None
        self._remove()  # the holder, empty now (none where the folder was made here)

    def discard(self) -> None:
        """Remove the temporary folder: the target stays as it was. Idempotent."""
        if self._done:
            return
        self._done = True
        _PENDING.pop(id(self), None)
        self._remove()

    def _remove(self) -> None:
        import shutil

        shutil.rmtree(self._holder, ignore_errors=True)


class _Named:
    """A file whose ``OSError`` names the output (``write`` and ``close`` on a full disk name
    no file of their own), for the writers that take a file (zipfile, matplotlib, NumPy)."""

    def __init__(self, fh, name: str):
        self._fh, self._name = fh, name

    def _named(self, fn, *args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except OSError as exc:
            if exc.errno is None:  # not the system's (io.UnsupportedOperation): as it is
                raise
            raise OSError(exc.errno, exc.strerror, self._name) from None

    def write(self, data):
        return self._named(self._fh.write, data)

    def flush(self) -> None:
        self._named(self._fh.flush)

    def close(self) -> None:
        self._named(self._fh.close)

    def __getattr__(self, name: str):  # seek() flushes too: every method names the file
        attr = getattr(self._fh, name)
        if not callable(attr):
            return attr
        return lambda *args, **kwargs: self._named(attr, *args, **kwargs)


def _open_fd(fd: int, text: bool):
    """The temporary file's handle (one place, where a test cuts writes short)."""
    return os.fdopen(fd, "w" if text else "wb")


def abort_pending() -> None:
    """Settle every output being written, for a process that must end at once (a second
    Ctrl-C, which cannot wait for the writers): those whole at their last flush
    (``keep_on_abort``: a trajectory) are committed, the others discarded. Safe from a
    signal handler: it takes no lock."""
    for out in list(_PENDING.values()):
        try:
            if out.keep_on_abort:
                out.commit()
            else:
                out.discard()
        except OSError:
            out.discard()


@atexit.register
def _discard_pending() -> None:
    """No temporary file outlives the process: one never committed (an object never closed)
    is removed at exit."""
    for out in list(_PENDING.values()):
        out.discard()


def write_bytes(path: str | Path, data: bytes, *, what: str | None = None) -> None:
    """``data`` as the whole file ``path`` (:class:`OutputFile`)."""
    with OutputFile(path, what=what) as fh:
        fh.write(data)


def write_text(path: str | Path, text: str, *, what: str | None = None) -> None:
    """``text`` as the whole file ``path`` (:class:`OutputFile`)."""
    with OutputFile(path, what=what, text=True) as fh:
        fh.write(text)


def write_image(path: str | Path, image: np.ndarray) -> None:
    """Write an image as ``cv2.imwrite`` does, but whole or not at all
    (:class:`OutputFile`) and raising ``OSError`` naming the file and the cause when it
    cannot be written (OpenCV only returns False, and on a full disk libpng prints ``libpng
    error: Write Error`` on its own line): encoded in memory by OpenCV, written by Python.

    Args:
      path: the file; its extension picks the format (``.png``).
      image: (H, W) or (H, W, 3) array as OpenCV writes it.
    """
    import cv2

    ok, data = cv2.imencode(Path(path).suffix or ".png", image)
    if not ok:
        raise OSError(errno.EINVAL, "OpenCV could not encode the image", str(path))
    write_bytes(path, data.tobytes())
