"""The persistent compilation cache: XLA programs compiled once per machine, not once per run
(host only).

Compiling the per-frame step takes 7-8 s on 2 cores and every ``jaxvo`` process paid it
again; loading it from JAX's persistent cache takes about 0.3 s. The ``jaxvo`` commands turn
the cache on by default (:func:`setup_compile_cache`), and so does the library on its first
use from Python (``Odometry``, ``run_sequence``: :func:`default_compile_cache`) unless the
program chose already (a JAX cache folder of its own, the cache turned off, or
:func:`setup_compile_cache` called), in a folder chosen by, first to last:

1. ``--compile-cache DIR`` or ``--no-compile-cache`` (``setup_compile_cache(option)``);
2. the environment variable ``JAXVO_COMPILE_CACHE`` (``off``, or a folder);
3. JAX's own ``JAX_COMPILATION_CACHE_DIR``, left as JAX configures it (the user already
   keeps a cache there, with its own size bound);
4. ``$XDG_CACHE_HOME/jaxvo/xla``, else ``~/.cache/jaxvo/xla``.

A jaxvo folder (1, 2, 4) holds one subfolder per jaxvo and JAX version
(``jaxvo-0.1.0_jax-0.7.2``), so an upgrade starts a new one and an old one can be deleted
whole. Within it JAX keys each program on the computation itself, the compile options, the
XLA flags, the backend and jaxlib's version, so a new configuration (another grid size,
hypothesis count) or changed code compiles afresh and never loads a stale program.

Several processes may share the folder (``jaxvo run`` over many sequences at once, or
``jaxvo study`` on several processes): the cache is bounded (:data:`MAX_BYTES`, least
recently used entries evicted), which makes JAX take a file lock around every read and
write, so no process reads an entry another is still writing, and only the first of two
processes that compiled the same program stores it. An entry left empty by a process
killed while writing it would be read, fail and never be rewritten; :func:`use_compile_cache`
removes such entries (under the same lock) before the first compile.

A busy or broken cache never fails a command: a lock another process holds past
:data:`LOCK_TIMEOUT_S`, or a folder that fails when repaired, turns the cache off with one
warning line; JAX's own errors reading or writing an entry (a full disk, a lock held past
its timeout) are said in one line, the first, instead of a warning per program.

JAX trusts what it loads from the cache: keep it in a folder only you can write to.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import NamedTuple, TextIO

from jaxvo.errors import InputError

ENV = "JAXVO_COMPILE_CACHE"
OFF = "off"
# Larger than every configuration's programs together (the per-frame step's program, a
# scan's about as large); bounded, so that JAX evicts old entries and locks the folder.
MAX_BYTES = 1 << 30
# Every program is stored, the tiny ones JAX compiles for eager operations too (a few dozen,
# small, each quick to compile): loading them shortens a later run's first frame several
# times over (docs/report/host_decisions.md).
MIN_COMPILE_SECONDS = 0.0
# The lock file JAX's bounded cache takes (jax._src.lru_cache); the repair takes it too.
_LOCK_NAME = ".lockfile"
_ENTRY_SUFFIX = "-cache"
# How long the repair waits for another process's hold on the lock (JAX's own wait, per
# entry read or written, is also 10 s) before the command goes on without the cache.
LOCK_TIMEOUT_S = 10.0
# The start of JAX's warnings for an entry it could not read or write (jax._src.compiler)
_JAX_CACHE_ERRORS = ("Error reading persistent compilation cache entry",
                     "Error writing persistent compilation cache entry")


class CacheChoice(NamedTuple):
    """Where compiled programs are kept, and why there."""

    folder: Path | None  # None: the cache is off
    source: str  # which setting chose it, in words (e.g. "--compile-cache", "default")


def choose_compile_cache(
    option: str | os.PathLike | None = None, *, environ: Mapping[str, str] | None = None
) -> CacheChoice:
    """The compile cache's folder from the option, the environment and the defaults, in the
    order of the module docstring (no file is touched).

    Args:
      option: ``--compile-cache`` (a folder), ``"off"`` (``--no-compile-cache``), or None
        when neither was given.
      environ: the environment (default ``os.environ``).
    Returns:
      :class:`CacheChoice`; a jaxvo folder gets its version subfolder appended.
    """
    env = os.environ if environ is None else environ
    for value, source in ((option, "--compile-cache"), (env.get(ENV), ENV)):
        if value is None or str(value) == "":
            continue
        if str(value).strip().lower() == OFF:
            return CacheChoice(None, f"{source} off" if source == ENV else "--no-compile-cache")
        return CacheChoice(_versioned(Path(value).expanduser()), source)
    if env.get("JAX_COMPILATION_CACHE_DIR"):
        return CacheChoice(Path(env["JAX_COMPILATION_CACHE_DIR"]).expanduser(),
                           "JAX_COMPILATION_CACHE_DIR")
    base = env.get("XDG_CACHE_HOME") or str(Path(env.get("HOME", "~")) / ".cache")
    return CacheChoice(_versioned(Path(base).expanduser() / "jaxvo" / "xla"), "default")


def _versioned(root: Path) -> Path:
    """``root/jaxvo-<version>_jax-<version>``: one subfolder per release pair."""
    import jax

    from jaxvo import __version__

    return root / f"jaxvo-{__version__}_jax-{jax.__version__}"


def use_compile_cache(folder: str | os.PathLike | None) -> None:
    """Point JAX's persistent compilation cache at ``folder`` (None: turn it off).

    Call it before the first compile of the process: JAX opens its cache once. Entries
    left empty by a killed process are removed first (see the module docstring).

    Args:
      folder: an existing, writable folder, or None.
    """
    import jax

    if folder is None:
        jax.config.update("jax_enable_compilation_cache", False)
        return
    _drop_empty_entries(Path(folder))
    _one_line_for_cache_errors(Path(folder), sys.stderr)
    jax.config.update("jax_enable_compilation_cache", True)
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    jax.config.update("jax_compilation_cache_max_size", MAX_BYTES)


def _drop_empty_entries(folder: Path) -> None:
    """Remove zero-byte cache entries (a writer killed between creating and writing one),
    under the lock JAX takes to write, so an entry being written now is never touched."""
    import filelock

    with filelock.FileLock(folder / _LOCK_NAME, timeout=LOCK_TIMEOUT_S):
        for entry in folder.glob(f"*{_ENTRY_SUFFIX}"):
            with contextlib.suppress(OSError):  # another process removed it first
                if entry.stat().st_size == 0:
                    entry.unlink()


_chosen = False  # this process has chosen its compile cache (setup_compile_cache)


def default_compile_cache(*, environ: Mapping[str, str] | None = None) -> CacheChoice | None:
    """jaxvo's compile cache for a program that uses the library without choosing one:
    what the commands use (:func:`setup_compile_cache` with no option), set up once a process,
    on the library's first use (``Odometry``, ``run_sequence``).

    Left as it is where the process chose already: :func:`setup_compile_cache` called (the
    commands, or a user's ``setup_compile_cache("off")``), a JAX cache folder configured
    (``JAX_COMPILATION_CACHE_DIR`` or ``jax_compilation_cache_dir``), or JAX's cache turned off
    (``jax_enable_compilation_cache`` False). ``JAXVO_COMPILE_CACHE=off`` turns it off. A
    folder that cannot be used is a warning, never an error: a library does not fail for its
    cache. JAX decides whether a process uses its cache at the first compile; the decision is
    taken again (``reset_cache``), so programs compiled before this call do not keep it off.

    Returns:
      the :class:`CacheChoice` set up, or None where the process had chosen.
    """
    global _chosen
    if _chosen:
        return None
    _chosen = True
    import jax

    if jax.config.jax_compilation_cache_dir or not jax.config.jax_enable_compilation_cache:
        return None
    import warnings

    try:
        choice = setup_compile_cache(None, environ=environ)
    except InputError as exc:  # JAXVO_COMPILE_CACHE names a folder that cannot be written
        warnings.warn(f"{exc}; running without the compile cache", stacklevel=3)
        use_compile_cache(None)
        choice = CacheChoice(None, f"off ({ENV} folder not writable)")
    from jax.experimental.compilation_cache import compilation_cache

    compilation_cache.reset_cache()
    return choice


def setup_compile_cache(
    option: str | os.PathLike | None = None,
    *,
    environ: Mapping[str, str] | None = None,
    stream: TextIO | None = None,
) -> CacheChoice:
    """Choose the compile cache's folder (:func:`choose_compile_cache`), create it and turn
    the cache on there, or off.

    A folder chosen by the option or the environment that cannot be written is an error;
    the default one only turns the cache off, with a warning (a read-only home folder must
    not stop a run).

    Args:
      option: ``--compile-cache`` DIR, ``"off"``, or None.
      environ: the environment (default ``os.environ``).
      stream: where the warning goes (default stderr).
    Returns:
      the :class:`CacheChoice` in force (``folder`` None when the cache is off).
    Raises:
      InputError: a folder given by the option or ``JAXVO_COMPILE_CACHE`` that cannot be
        created or written.
    """
    global _chosen
    _chosen = True
    choice = choose_compile_cache(option, environ=environ)
    if choice.source == "JAX_COMPILATION_CACHE_DIR":
        return choice  # JAX reads it itself; its size bound and thresholds are the user's
    if choice.folder is not None:
        from jaxvo.host.readers.io import output_folder

        try:
            output_folder(choice.folder, what=f"compile cache ({choice.source})")
        except InputError as exc:
            if choice.source in ("--compile-cache", ENV):
                raise
            print(f"jaxvo: warning: {exc}; running without it", file=stream or sys.stderr)
            choice = CacheChoice(None, f"off ({choice.source} folder not writable)")
    try:
        use_compile_cache(choice.folder)
    except OSError as exc:  # filelock's Timeout is one: another process holds the lock
        import filelock

        why = (f"is locked by another process for over {LOCK_TIMEOUT_S:g} s"
               if isinstance(exc, filelock.Timeout)
               else f"cannot be used ({exc.strerror or exc})")
        print(f"jaxvo: warning: compile cache {choice.folder} {why}; running without it",
              file=stream or sys.stderr)
        use_compile_cache(None)
        choice = CacheChoice(None, f"off ({choice.source} folder busy or broken)")
    return choice


_funnel_installed = False


def _one_line_for_cache_errors(folder: Path, stream: TextIO) -> None:
    """Say JAX's warnings about cache entries it could not read or write (a full disk: 14
    lines a run) as one line, the first, and none after it: a compile goes on without the
    entry either way. Other warnings pass as before (``warnings.showwarning``, the hook
    Python offers for this)."""
    global _funnel_installed
    import warnings

    if _funnel_installed:
        return
    previous = warnings.showwarning
    said = False

    def show(message, category, filename, lineno, file=None, line=None):
        nonlocal said
        text = str(message)
        if not text.startswith(_JAX_CACHE_ERRORS):
            previous(message, category, filename, lineno, file, line)
        elif not said:
            said = True
            what = "reading" if text.startswith(_JAX_CACHE_ERRORS[0]) else "writing"
            why = text.split("': ", 1)[-1]
            stream.write(f"jaxvo: warning: compile cache {folder}: {what} an entry failed "
                         f"({why}); going on without it (further cache errors not shown)\n")
            stream.flush()

    warnings.showwarning = show
    _funnel_installed = True


def add_compile_cache_options(parser) -> None:
    """``--compile-cache DIR`` and ``--no-compile-cache`` on an argparse parser (dest
    ``compile_cache``: the folder, ``"off"``, or None when neither is given)."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "--compile-cache", metavar="DIR",
        help="keep compiled XLA programs in DIR (a subfolder per jaxvo and JAX version), so "
        f"later runs skip the compile (default: ${ENV}, else $XDG_CACHE_HOME/jaxvo/xla or "
        f"~/.cache/jaxvo/xla; {ENV}=off turns it off)")
    group.add_argument(
        "--no-compile-cache", dest="compile_cache", action="store_const", const=OFF,
        help="compile afresh and store nothing")


# --- saying that a compile is under way ----------------------------------------------------

# JAX's monitoring events (jax._src.dispatch.BACKEND_COMPILE_EVENT: a scalar when XLA's
# compile of a program starts, a duration when it ends, a persistent cache lookup included;
# jax._src.compiler: an event when the program came from the persistent cache, and the
# compile time that saved, the stored compile time (whole seconds) less the load's).
_COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"
_CACHE_HIT_EVENT = "/jax/compilation_cache/cache_hits"
_SAVED_EVENT = "/jax/compilation_cache/compile_time_saved_sec"

_watch: _Watch | None = None  # the announce_compile block in force, if any
_listening = False


class CompileNote(NamedTuple):
    """A program that takes at least ``after`` seconds to compile: compiled now, or loaded
    from the persistent cache."""

    seconds: float  # the compile's or the load's
    from_cache: bool


class _Watch:
    """The state of one :func:`announce_compile` block (compiles on its own thread)."""

    def __init__(self, what: str, stream: TextIO | None, after: float, cached: bool):
        self.what, self.stream, self.after, self.cached = what, stream, after, cached
        self.thread = threading.get_ident()
        self.lock = threading.Lock()
        self.timer: threading.Timer | None = None
        self.compiling = self.hit = self.said = False
        self.saved = 0.0  # compile seconds a load from the cache saved
        self.start = 0.0
        self.notes: list[CompileNote] = []

    def started(self) -> None:
        with self.lock:
            self.compiling, self.hit, self.saved = True, False, 0.0
            self.start = time.perf_counter()
        if self.stream is not None:
            self.timer = threading.Timer(self.after, self._say)
            self.timer.daemon = True
            self.timer.start()

    def _say(self) -> None:
        """On the timer's thread: the compile goes on and no cached program came."""
        with self.lock:
            if not self.compiling or self.hit:
                return
            # a load from the cache is known only when it ends (JAX reports the hit
            # then), and under load it can take seconds: the line says what is certain
            if self.cached:
                self.stream.write(f"jaxvo: preparing {self.what} (compiled once per machine "
                                  "and cached) ...")
            else:
                self.stream.write(f"jaxvo: compiling {self.what} (the compile cache is "
                                  "off) ...")
            self.stream.flush()
            self.said = True

    def finished(self, seconds: float) -> None:
        if self.timer is not None:
            self.timer.cancel()
        with self.lock:
            self.compiling = False
            # a load notes the programs that compiled slowly, not the tiny eager ones
            if seconds + (self.saved if self.hit else 0.0) >= self.after:
                self.notes.append(CompileNote(seconds, self.hit))
            if self.said:
                self.said = False
                if self.hit:
                    done = "loaded from the compile cache in"
                elif self.cached:
                    done = "compiled (first run with these settings on this machine) in"
                else:
                    done = "compiled in"
                self.stream.write(f" {done} {seconds:.1f} s\n")
                self.stream.flush()

    def close(self) -> None:
        if self.timer is not None:
            self.timer.cancel()
        with self.lock:
            if self.said:  # the compile raised: end the line
                self.stream.write("\n")
                self.said = False


def _on_scalar(event: str, value: float, **kwargs) -> None:
    w = _watch
    if event == _COMPILE_EVENT and w is not None and threading.get_ident() == w.thread:
        w.started()


def _on_event(event: str, **kwargs) -> None:
    w = _watch
    if event == _CACHE_HIT_EVENT and w is not None and threading.get_ident() == w.thread:
        w.hit = True


def _on_duration(event: str, duration: float, **kwargs) -> None:
    w = _watch
    if w is None or threading.get_ident() != w.thread:
        return
    if event == _SAVED_EVENT:
        w.saved = duration
    elif event == _COMPILE_EVENT:
        w.finished(duration)


@contextlib.contextmanager
def announce_compile(
    what: str, *, stream: TextIO | None = None, after: float = 1.0
) -> Iterator[list[CompileNote]]:
    """Say on ``stream`` that ``what`` is compiling, and how long it took, when a compile on
    this thread inside the block goes on for ``after`` seconds: ``jaxvo: preparing the
    per-frame step (compiled once per machine and cached) ... compiled (first run with these
    settings on this machine) in 7.4 s``, or ``... loaded from the compile cache in 3.6 s``
    where the persistent cache had it (a fraction of a second on a quiet machine, seconds
    on a busy one; whether the cache has it is known only when the load ends). Nothing is
    said for a program that is ready within ``after`` seconds, nor for the quick compiles
    of eager operations.

    Args:
      what: what compiles, in words (``"the per-frame step"``).
      stream: where to say it; None says nothing (the notes are still taken).
      after: seconds a compile runs before it is announced.
    Returns:
      (as the ``with`` target) a list that gets a :class:`CompileNote` for each program
      that took ``after`` seconds or more to compile, now or when it was stored (JAX stores
      whole seconds: a program that compiled in under a second is not noted when loaded).
    """
    global _watch, _listening
    import jax

    if not _listening:  # listeners cannot be removed in every JAX: installed once
        jax.monitoring.register_scalar_listener(_on_scalar)
        jax.monitoring.register_event_listener(_on_event)
        jax.monitoring.register_event_duration_secs_listener(_on_duration)
        _listening = True
    cached = bool(jax.config.jax_enable_compilation_cache
                  and jax.config.jax_compilation_cache_dir)
    watch = _Watch(what, stream, after, cached)
    outer, _watch = _watch, watch
    try:
        yield watch.notes
    finally:
        watch.close()
        _watch = outer


# --- programs kept traced and lowered ------------------------------------------------------

# JAX's cache keeps a compiled program, keyed on its lowered computation, so a later process
# still traces and lowers the per-frame step before the cache can find it: two thirds of the
# first pose's wait (bench/bench_first_pose.py). An exported program (jax.export: the lowered
# computation and its argument types, serialised) skips both; it is kept beside JAX's entries,
# keyed on what could change the computation (jaxvo's source, JAX's version and settings, the
# static settings and the arguments' types), and compiled through JAX's cache as any program.
_EXPORTED = "jaxvo-exported"
_programs: dict[str, Callable] = {}  # key -> the program, loaded or exported in this process
_registered: set[type] = set()  # NamedTuple types made known to jax.export's serialisation
_source_digest: str | None = None


def exported_program(name: str, fun: Callable, args: tuple, *, static: str) -> Callable | None:
    """``jax.jit(fun)`` for arguments of the types of ``args``, kept exported in the compile
    cache folder so that a later process loads it instead of tracing and lowering ``fun``.

    Args:
      name: what the program is, for its file's name (``"step"``).
      fun: the function, of ``args`` positionally; its output a pytree of arrays.
      args: example arguments (their types and shapes are the program's).
      static: what else sets the computation (the static settings, in words: ``repr(cfg)``).
    Returns:
      a jitted callable of arguments of the same types, or None where the compile cache is
      off (JAX's folder unset or disabled), the arguments are not on the CPU, or
      ``jax.export`` cannot serialise (no ``flatbuffers``): then the caller runs ``fun`` as
      it would have.
    """
    import jax

    if not (jax.config.jax_enable_compilation_cache and jax.config.jax_compilation_cache_dir):
        return None
    try:
        from jax import export
        from jax._src.export import serialization  # noqa: F401 (needs flatbuffers)
    except ImportError:
        return None
    # the CPU's programs alone: Odometry's step runs there unless told otherwise, and an
    # export is for a platform named as jax.export names it, not as a device does (gpu)
    on = {d.platform for x in jax.tree.leaves(args) if isinstance(x, jax.Array)
          for d in x.devices()} or {jax.default_backend()}
    if on != {"cpu"}:
        return None
    key = _program_key(name, args, static)
    if key in _programs:
        return _programs[key]
    path = Path(jax.config.jax_compilation_cache_dir) / _EXPORTED / f"{name}-{key}"
    exported = _read_exported(path)
    if exported is None:
        try:
            exported = export.export(jax.jit(fun), platforms=["cpu"])(*args)
        except Exception:  # noqa: BLE001 (what cannot be exported runs as it is: jit, traced)
            return None
        _write_exported(path, exported)
    program = _programs[key] = jax.jit(exported.call)
    return program


def _program_key(name: str, args: tuple, static: str) -> str:
    """A digest of everything the exported computation depends on."""
    import hashlib

    import jax
    import jaxlib
    import numpy as np

    def leaf(x) -> str:
        sharding = getattr(x, "sharding", None)
        return (f"{np.shape(x)} {getattr(x, 'dtype', type(x).__name__)} "
                f"{getattr(x, 'weak_type', False)} {sharding}")

    leaves, tree = jax.tree.flatten(args)
    parts = [name, static, str(tree), *map(leaf, leaves), jax.__version__, jaxlib.__version__,
             os.environ.get("XLA_FLAGS", ""), _jaxvo_source(),
             repr(sorted((k, repr(v)) for k, v in jax.config.values.items()))]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:32]


def _jaxvo_source() -> str:
    """A digest of jaxvo's Python source, read once a process: changed code never loads a
    program exported from older code."""
    global _source_digest
    if _source_digest is None:
        import hashlib

        import jaxvo

        root = Path(jaxvo.__file__).resolve().parent
        h = hashlib.sha256()
        for path in sorted(root.rglob("*.py")):
            h.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes())
        _source_digest = h.hexdigest()
    return _source_digest


def _namedtuples(trees) -> list[type]:
    """The NamedTuple types in pytree structures (jax.export serialises them by name)."""
    found: list[type] = []

    def walk(node) -> None:
        data = node.node_data()
        if (data is not None and isinstance(data[0], type) and hasattr(data[0], "_fields")
                and data[0] not in found):
            found.append(data[0])
        for child in node.children():
            walk(child)

    for tree in trees:
        walk(tree)
    return found


def _register(types) -> None:
    from jax import export

    for t in types:
        if t not in _registered:
            export.register_namedtuple_serialization(
                t, serialized_name=f"{t.__module__}.{t.__qualname__}")
            _registered.add(t)


def _read_exported(path: Path):
    """The program exported at ``path``, or None (absent, or unreadable: exported again)."""
    import importlib
    import json

    from jax import export

    try:
        data = path.read_bytes()
        header, blob = data.split(b"\n", 1)
        types = []
        for name in json.loads(header):
            module, _, qualname = name.rpartition(".")
            types.append(getattr(importlib.import_module(module), qualname))
        _register(types)
        return export.deserialize(bytearray(blob))
    except Exception:  # noqa: BLE001 (a broken entry, whatever the fault: exported again)
        return None


def _write_exported(path: Path, exported) -> None:
    """``exported`` at ``path``, whole or not at all; a folder that cannot be written only
    leaves the next process to export it again."""
    import json

    types = _namedtuples((exported.in_tree, exported.out_tree))
    _register(types)
    header = json.dumps([f"{t.__module__}.{t.__qualname__}" for t in types]).encode()
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(exist_ok=True)
        tmp.write_bytes(header + b"\n" + exported.serialize())
        os.replace(tmp, path)
    except OSError:
        with contextlib.suppress(OSError):
            tmp.unlink()
