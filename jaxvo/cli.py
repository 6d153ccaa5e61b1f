"""The ``jaxvo`` command line: subcommands, one-line errors, exit codes scripts can trust.

Exit codes: 0 success, 1 the job ran but failed its purpose (e.g. every frame skipped),
2 bad input or usage, 130 interrupted.

Each subcommand lives in ``jaxvo/commands/<name>.py`` and exposes
``add_arguments(parser)`` and ``run(args) -> int``; modules are imported only when their
command runs, so ``jaxvo eval`` never pays for importing JAX.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from jaxvo.errors import InputError

# name -> (module, one-line help); the order is the order --help lists them in.
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("jaxvo.commands.demo", "synthesise a dynamic scene, run jaxvo and peers, score them"),
    "run": ("jaxvo.commands.run", "odometry over a recorded TUM-layout RGB-D sequence"),
    "eval": ("jaxvo.commands.eval", "score a trajectory against ground truth (ATE, RPE)"),
    "synth": ("jaxvo.commands.synth", "render a synthetic dynamic RGB-D sequence with ground truth"),
    "study": ("jaxvo.commands.study", "run and score a study over sequences, settings and seeds"),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jaxvo",
        description="Robust RGB-D visual odometry for dynamic scenes (rigid motion "
        "segmentation in JAX).",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module)
        importlib.import_module(module).add_arguments(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(importlib.import_module(args._module).run(args) or 0)
    except (InputError, FileNotFoundError, IsADirectoryError, NotADirectoryError) as exc:
        msg = str(exc) if isinstance(exc, InputError) else f"{exc.strerror}: {exc.filename}"
        print(f"jaxvo: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("jaxvo: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
