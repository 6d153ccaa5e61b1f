"""The ``jaxvo`` command line: subcommands, one-line errors, exit statuses scripts can trust.

Exit statuses (:data:`EXIT_STATUSES`, also in ``jaxvo --help``): 0 success; 1 the command
ran but estimated nothing (no frame pair gave a camera motion); 2 bad input or usage (a
missing, unreadable or malformed file or option, an output that cannot be written), said in
one line ``jaxvo: error: ...``; 130 interrupted (what was computed so far is kept).

Each subcommand lives in ``jaxvo/cli/<name>.py`` and exposes
``add_arguments(parser)`` and ``run(args) -> int``; modules are imported only when their
command runs. A command that compiles, or reads files, also exposes ``prepare(args)``:
every check of its options and files, without JAX, so that a one-line answer comes at once
(``jaxvo run /missing``: 0.75-0.95 s with JAX loaded first); the answers that need no
NumPy (a path that is not there, an unknown name, an option out of range, an output that
cannot be written) come before NumPy loads, from the light checks at its start
(:mod:`jaxvo.cli.inputs` for paths, :mod:`jaxvo.host.writers.outputs` for outputs).
``run(args, prepared)`` takes what it returns, after the compile cache is set up (which
loads JAX).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import signal
import sys
from collections.abc import Iterable, Iterator

from jaxvo import __version__
from jaxvo.errors import InputError
from jaxvo.host.services.compile_cache import add_compile_cache_options, setup_compile_cache

EXIT_OK, EXIT_NOTHING_ESTIMATED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130
EXIT_PIPE = 141  # 128 + SIGPIPE: the reader of standard output closed it

EXIT_STATUSES = """\
exit status:
  0    success
  1    the command ran but estimated nothing: no frame pair gave a camera motion
       (every pair skipped or dropped; the summary says why)
  2    bad input or usage: a missing, unreadable or malformed file or option, or an
       output that cannot be written (one line 'jaxvo: error: ...')
  130  interrupted (Ctrl-C; 143: SIGTERM); what was computed so far is kept, each
       file whole
  141  the reader of standard output closed it (jaxvo run --out - | head); quiet"""

# name -> (module, one-line help); the order is the order --help lists them in.
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("jaxvo.cli.demo", "synthesise a dynamic scene, run jaxvo and peers, score them"),
    "run": ("jaxvo.cli.run", "odometry over a recorded TUM-layout RGB-D sequence"),
    "map": ("jaxvo.cli.map", "fuse a run's depth into a static map, the movers left out"),
    "eval": ("jaxvo.cli.eval", "score a trajectory against ground truth (ATE, RPE)"),
    "synth": ("jaxvo.cli.synth", "render a synthetic dynamic RGB-D sequence with ground truth"),
    "study": ("jaxvo.cli.study", "run and score a study over sequences, settings and seeds"),
    "data": ("jaxvo.cli.data", "download the TUM RGB-D and Bonn RGB-D Dynamic sequences"),
}


# The commands that compile XLA programs: they take --compile-cache / --no-compile-cache.
COMPILING = ("demo", "run", "synth", "study")


def add_seed_option(p: argparse.ArgumentParser, what: str) -> None:
    """``--seed``, default 0, in the range every command checks (``errors.check_seed``);
    ``what`` says what it seeds."""
    p.add_argument("--seed", type=int, default=0, help=f"{what}, 0 .. 2**32-1 (default 0)")


def add_summary_options(p: argparse.ArgumentParser, *, summary: str, quiet: str) -> None:
    """``--json`` (the command's ``summary`` printed as JSON) and ``--quiet`` / ``-q``
    (``quiet``: what it leaves out), as the commands that compute and report give them."""
    p.add_argument("--json", action="store_true", help=f"print {summary} as JSON")
    p.add_argument("--quiet", "-q", action="store_true", help=quiet)


def build_parser(commands: Iterable[str] = tuple(COMMANDS)) -> argparse.ArgumentParser:
    """The ``jaxvo`` parser; ``commands``: the subcommands whose options it takes (their
    modules imported), the others listed by name alone. :func:`main` asks for the one its
    arguments name, so that a one-line answer imports no other command's module."""
    parser = argparse.ArgumentParser(
        prog="jaxvo",
        description="Robust RGB-D visual odometry for dynamic scenes (rigid motion "
        "segmentation in JAX).",
        epilog=EXIT_STATUSES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"jaxvo {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module)
        if name not in commands:
            continue
        importlib.import_module(module).add_arguments(p)
        if name in COMPILING:
            add_compile_cache_options(p)
    return parser


class StopRequest:
    """Whether Ctrl-C (or SIGTERM) came inside :func:`interrupt_at_safe_points`; calling it
    raises ``KeyboardInterrupt`` then, at a point the caller chose as safe."""

    def __init__(self) -> None:
        self.requested = False
        self.signum: int | None = None  # the signal that asked to stop

    def __call__(self) -> None:
        if self.requested:
            raise KeyboardInterrupt

    @property
    def exit_status(self) -> int:
        """128 + the signal's number, as shells report a process a signal ended (130 for
        Ctrl-C, 143 for SIGTERM)."""
        return 128 + (self.signum or signal.SIGINT)


# the stop request of the command under way: one per process, so that a command's own
# `with interrupt_at_safe_points()` takes the one main() installed before JAX loaded
_CURRENT: StopRequest | None = None


@contextlib.contextmanager
def interrupt_at_safe_points(*, safe: bool = True) -> Iterator[StopRequest]:
    """Turn Ctrl-C and SIGTERM into a request that the work checks between steps.

    Python raises ``KeyboardInterrupt`` wherever the main thread is. Inside JAX's
    ``backend.compile_and_load`` (the first frame's 3-25 s compile) the main thread stops
    waiting for the compile, which goes on in a worker of XLA's thread pool; the
    interpreter then exits and tears down the JAX client under it, and the worker crashed
    on freed state (core dump: ``PjRtLoadedExecutable::Create`` calling a null pointer in
    ``SingleDeviceSharding::Create`` while the main thread joined the pool in
    ``~ThreadPool``; exit -11 in 8 of 8 tries interrupting 0.3-3 s into the compile). The
    grid-flow helper thread plays no part. While JAX loads, a ``KeyboardInterrupt`` raised
    in its garbage-collection callback was swallowed (``Exception ignored in:
    <function _xla_gc_callback>``) and the run went on to exit 0.

    Here the first Ctrl-C (or SIGTERM, as a process manager stops a program) only sets a
    flag, said on stderr; the caller calls the yielded :class:`StopRequest` between steps,
    where stopping is safe, and it raises ``KeyboardInterrupt`` there. With ``safe=False``
    (a command with no JAX under way) the first one raises ``KeyboardInterrupt`` at once,
    as Python does. A second one ends the process at once with 128 + the signal's number,
    without the interpreter's clean-up that crashed: the outputs being written are settled
    first (:func:`jaxvo.host.writers.outputs.abort_pending`: the trajectory, whole at every pose,
    is kept; a file half-written is not). Off the main thread signals are left as they are;
    a signal the process started with ignored stays ignored, each on its own: a shell
    without job control starts a background job (``jaxvo run ... &`` in a script) with
    SIGINT ignored, and its ``kill`` (SIGTERM) must still stop the run with what was
    finished kept. Nested, it yields the request already installed.
    """
    global _CURRENT
    if _CURRENT is not None:
        yield _CURRENT
        return
    stop = StopRequest()

    def on_signal(signum, frame) -> None:
        if stop.requested:
            with contextlib.suppress(OSError, ValueError):
                sys.stdout.flush()
            with contextlib.suppress(OSError, ValueError):
                print("jaxvo: interrupted again: stopping at once", file=sys.stderr,
                      flush=True)
            outputs = sys.modules.get("jaxvo.host.writers.outputs")  # not loaded: nothing written
            if outputs is not None:
                outputs.abort_pending()
            os._exit(128 + signum)
        stop.requested, stop.signum = True, signum
        if not safe:
            raise KeyboardInterrupt
        with contextlib.suppress(OSError, ValueError):
            print("jaxvo: interrupt: stopping after the current step (Ctrl-C again to stop "
                  "at once)", file=sys.stderr, flush=True)

    previous = {}
    try:
        for sig in (signal.SIGINT, signal.SIGTERM):
            if signal.getsignal(sig) is not signal.SIG_IGN:
                previous[sig] = signal.signal(sig, on_signal)
    except ValueError:  # not the main thread
        previous = {}
    _CURRENT = stop if previous else None
    try:
        yield stop
    finally:
        _CURRENT = None
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def quiet_interrupts_at_exit() -> None:
    """From the interpreter's exit on, Ctrl-C or SIGTERM ends the process at once with
    128 + the signal's number, quietly. JAX's own clean-up at exit (its backends and
    caches released) takes a moment, and an interrupt landing there printed a
    ``KeyboardInterrupt`` traceback after a finished command. Call it once JAX is loaded:
    exit handlers run last registered first, so this one runs before JAX's."""
    import atexit

    atexit.unregister(_exit_quietly_on_signals)  # once, however often it is asked
    atexit.register(_exit_quietly_on_signals)


def _exit_quietly_on_signals() -> None:
    def on_signal(signum, frame) -> None:
        os._exit(128 + signum)

    with contextlib.suppress(ValueError):  # not the main thread
        for sig in (signal.SIGINT, signal.SIGTERM):
            if signal.getsignal(sig) is not signal.SIG_IGN:
                signal.signal(sig, on_signal)


def _os_error(exc: OSError) -> str:
    """One line for an operating-system error: the file, then what went wrong."""
    what = exc.strerror or str(exc)
    return f"{exc.filename}: {what}" if exc.filename else what


def _standard_streams() -> None:
    """Standard input, output and error that are closed (``>&-``) become the null device,
    so that no file this command opens takes their descriptor (a library's message on fd 2
    would land in it) and printing ends nowhere quietly. A closed standard output is
    remembered: ``--out -`` is refused then (:func:`jaxvo.host.writers.outputs.output_file`), whose
    module loads only then."""
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            null = os.open(os.devnull, os.O_RDWR)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)
            if fd == 1:
                _stdout_closed()
    if sys.stdout is None:
        _stdout_closed()
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 (for the process's life)
    if sys.stderr is None:
        sys.stderr = open(os.devnull, "w")  # noqa: SIM115 (for the process's life)


def _stdout_closed() -> None:
    from jaxvo.host.writers import outputs

    outputs.STDOUT_CLOSED = True


def _one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning as one line ``jaxvo: warning: ...``, as the commands' own warnings."""
    with contextlib.suppress(OSError, ValueError):
        print(f"jaxvo: warning: {message}", file=sys.stderr)


def _quiet_end_of_pipe() -> int:
    """The reader of standard output went away (``jaxvo run --out - | head``): not an
    error, as for other command-line tools. Standard output is pointed at the null device
    so that the interpreter's last flush says nothing; the status is 141 (128 + SIGPIPE),
    what a shell reports for a tool the closed pipe ended."""
    with contextlib.suppress(OSError, ValueError, AttributeError):  # no file descriptor
        null = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(null, sys.stdout.fileno())
        finally:
            os.close(null)
    return EXIT_PIPE


def _named_command(argv: list[str] | None) -> tuple[str, ...]:
    """The subcommand the arguments name (the first word that is no option: the top level
    takes no option with a value), or none (``jaxvo --help``, a misspelt command)."""
    words = [a for a in (sys.argv[1:] if argv is None else argv) if not a.startswith("-")]
    return tuple(words[:1]) if words and words[0] in COMMANDS else ()


def main(argv: list[str] | None = None) -> int:
    import warnings

    _standard_streams()
    # Rerun's own log lines (a full disk: ERROR and WARN lines of its file writer) stay
    # quiet; the command says what failed in one line of its own (RUST_LOG set wins)
    os.environ.setdefault("RUST_LOG", "off")
    stop = None
    with warnings.catch_warnings():
        warnings.showwarning = _one_line_warning
        try:
            try:  # --help, --version and usage errors end in SystemExit, as argparse's do
                args = build_parser(_named_command(argv)).parse_args(argv)
            except SystemExit:
                sys.stdout.flush()  # a closed pipe (jaxvo --help | head -1) is found here
                raise
            module = importlib.import_module(args._module)
            if not hasattr(module, "prepare"):
                with interrupt_at_safe_points(safe=False) as stop:
                    status = int(module.run(args) or 0)
            else:
                prepared = module.prepare(args)  # options and files checked before JAX loads
                # from here a Ctrl-C waits for a safe point: JAX loads and compiles
                with interrupt_at_safe_points(safe=args.command in COMPILING) as stop:
                    if args.command in COMPILING:  # before the command's first compile
                        setup_compile_cache(args.compile_cache)
                    stop()
                    status = int(module.run(args, prepared) or 0)
            sys.stdout.flush()  # a closed pipe is found here, not at the interpreter's exit
            return status
        except BrokenPipeError:  # also an output FIFO whose reader left: the same answer
            return _quiet_end_of_pipe()
        except InputError as exc:
            msg = str(exc)
        except OSError as exc:  # a file that vanished or cannot be written mid-run
            msg = _os_error(exc)
        except KeyboardInterrupt:
            with contextlib.suppress(OSError, ValueError):
                print("jaxvo: interrupted", file=sys.stderr)
            return stop.exit_status if stop is not None and stop.requested else (
                EXIT_INTERRUPTED)
    with contextlib.suppress(OSError, ValueError):
        print(f"jaxvo: error: {msg}", file=sys.stderr)
    return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
