"""The ``jaxvo`` command line: subcommands, one-line errors, exit statuses scripts can trust.

Exit statuses (:data:`EXIT_STATUSES`, also in ``jaxvo --help``): 0 success; 1 the command
ran but estimated nothing (no frame pair gave a camera motion); 2 bad input or usage (a
missing, unreadable or malformed file or option, an output that cannot be written), said in
one line ``jaxvo: error: ...``; 130 interrupted (what was computed so far is kept).

Each subcommand lives in ``jaxvo/cli/<name>.py`` and exposes
``add_arguments(parser)`` and ``run(args) -> int``; modules are imported only when their
command runs. A command that compiles also exposes ``prepare(args)``: every check of its
options and files, without JAX, so that a one-line answer comes at once (``jaxvo run
/missing``: 0.75-0.95 s with JAX loaded first); ``run(args, prepared)`` takes what it
returns, after the compile cache is set up (which loads JAX).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import signal
import sys
from collections.abc import Iterator

from jaxvo import __version__
from jaxvo.errors import InputError
from jaxvo.host.compile_cache import add_compile_cache_options, setup_compile_cache

EXIT_OK, EXIT_NOTHING_ESTIMATED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130

EXIT_STATUSES = """\
exit status:
  0    success
  1    the command ran but estimated nothing: no frame pair gave a camera motion
       (every pair skipped or dropped; the summary says why)
  2    bad input or usage: a missing, unreadable or malformed file or option, or an
       output that cannot be written (one line 'jaxvo: error: ...')
  130  interrupted (Ctrl-C); what was computed so far is kept"""

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


def build_parser() -> argparse.ArgumentParser:
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
        importlib.import_module(module).add_arguments(p)
        if name in COMPILING:
            add_compile_cache_options(p)
    return parser


class StopRequest:
    """Whether Ctrl-C was pressed inside :func:`interrupt_at_safe_points`; calling it raises
    ``KeyboardInterrupt`` then, at a point the caller chose as safe."""

    def __init__(self) -> None:
        self.requested = False

    def __call__(self) -> None:
        if self.requested:
            raise KeyboardInterrupt


@contextlib.contextmanager
def interrupt_at_safe_points() -> Iterator[StopRequest]:
    """Turn Ctrl-C into a request that the work checks between steps.

    Python raises ``KeyboardInterrupt`` wherever the main thread is. Inside JAX's
    ``backend.compile_and_load`` (the first frame's 3-25 s compile) the main thread stops
    waiting for the compile, which goes on in a worker of XLA's thread pool; the
    interpreter then exits and tears down the JAX client under it, and the worker crashed
    on freed state (core dump: ``PjRtLoadedExecutable::Create`` calling a null pointer in
    ``SingleDeviceSharding::Create`` while the main thread joined the pool in
    ``~ThreadPool``; exit -11 in 8 of 8 tries interrupting 0.3-3 s into the compile). The
    grid-flow helper thread plays no part.

    Here the first Ctrl-C only sets a flag, said on stderr; the caller calls the yielded
    :class:`StopRequest` between steps, where stopping is safe, and it raises
    ``KeyboardInterrupt`` there. A second Ctrl-C ends the process at once with status 130,
    without the interpreter's clean-up that crashed (every pose written so far is already
    flushed to disk). Off the main thread, or where SIGINT is ignored, interrupts are left
    as they are.
    """
    stop = StopRequest()

    def on_sigint(signum, frame) -> None:
        if stop.requested:
            sys.stdout.flush()
            print("jaxvo: interrupted again: stopping at once", file=sys.stderr, flush=True)
            os._exit(EXIT_INTERRUPTED)
        stop.requested = True
        print("jaxvo: interrupt: stopping after the current step (Ctrl-C again to stop at "
              "once)", file=sys.stderr, flush=True)

    try:
        if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
            previous = None
        else:
            previous = signal.signal(signal.SIGINT, on_sigint)
    except ValueError:  # not the main thread
        previous = None
    try:
        yield stop
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


def _os_error(exc: OSError) -> str:
    """One line for an operating-system error: the file, then what went wrong."""
    what = exc.strerror or str(exc)
    return f"{exc.filename}: {what}" if exc.filename else what


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        module = importlib.import_module(args._module)
        if not hasattr(module, "prepare"):
            return int(module.run(args) or 0)
        prepared = module.prepare(args)  # options and files checked before JAX loads
        if args.command in COMPILING:  # before the command's first compile
            setup_compile_cache(args.compile_cache)
        return int(module.run(args, prepared) or 0)
    except InputError as exc:
        msg = str(exc)
    except OSError as exc:  # a file that vanished or cannot be written mid-run
        msg = _os_error(exc)
    except KeyboardInterrupt:
        print("jaxvo: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    print(f"jaxvo: error: {msg}", file=sys.stderr)
    return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
