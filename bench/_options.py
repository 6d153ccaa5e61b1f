"""The benches' command-line options, each checked before any work: one line ``error: ...``
(argparse's ``ap.error``, exit 2), never a traceback after minutes of work.

Two steps, the same in every script. Each value alone is an argparse ``type`` here
(:func:`count`, :func:`config_setting`, :func:`params_setting`); what only the options
together decide (a pair of settings, a setting at the image's size, a case name against the
cases, the data a script reads) is :func:`check_options`, called right after
``parse_args``.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable, Iterable

from jaxvo.config import Config, Params, check_config, check_params, config_fields, setting_problem
from jaxvo.errors import InputError
from jaxvo.host.readers.io import data_root


def count(least: int = 1) -> Callable[[str], int]:
    """An argparse ``type``: a whole number of at least ``least`` (seeds, frames)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is no whole number") from None
        if value < least:
            raise argparse.ArgumentTypeError(f"must be at least {least}, got {value}")
        return value

    return parse


def _setting(defaults, text: str) -> tuple[str, object]:
    """``NAME=VALUE`` as ``(name, value)``, the value read as the type of ``defaults``'s
    field (a bool from 1/true/yes/on or 0/false/no/off); ``ValueError`` in one line for an
    unknown name or a value of the wrong type."""
    name, sep, value = text.partition("=")
    fields = defaults._fields if isinstance(defaults, tuple) else [
        f.name for f in config_fields().values()]
    if not sep or name not in fields:
        raise ValueError(f"{text!r}: want NAME=VALUE, NAME one of {', '.join(fields)}")
    kind = type(getattr(defaults, name))
    if kind is bool:
        if value.lower() not in ("1", "true", "yes", "on", "0", "false", "no", "off"):
            raise ValueError(f"{text!r}: {name} is true or false")
        return name, value.lower() in ("1", "true", "yes", "on")
    try:
        return name, kind(value)
    except ValueError:
        want = {int: "an integer", float: "a number"}.get(kind, kind.__name__)
        raise ValueError(f"{text!r}: {name} must be {want}") from None


def config_from(pairs: list[str]) -> Config:
    """``Config`` with ``NAME=VALUE`` pairs set, each value read as its field's type."""
    return dataclasses.replace(Config(), **dict(_setting(Config(), a) for a in pairs))


def params_from(pairs: list[str]) -> Params:
    """``Params`` with ``NAME=VALUE`` pairs set (floats)."""
    return Params()._replace(**{k: float(v) for k, v in (_setting(Params(), a) for a in pairs)})


def _checked(text: str, build: Callable, check: Callable) -> str:
    """``text`` (``NAME=VALUE``) kept as given once ``check(build([text]))`` passes, else
    argparse's one-line error."""
    try:
        check(build([text]))
    except (ValueError, InputError) as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return text


def config_setting(text: str) -> str:
    """An argparse ``type`` for a ``--config NAME=VALUE``: its value checked alone, kept as
    given (what the settings decide together :func:`check_options` checks)."""
    name = text.partition("=")[0]

    def check(cfg: Config) -> None:
        problem = setting_problem(name, getattr(cfg, name))
        if problem:
            raise InputError(f"Config.{name} {problem}")

    return _checked(text, config_from, check)


def params_setting(text: str) -> str:
    """An argparse ``type`` for a ``--set NAME=VALUE`` (a Params value): checked alone, kept."""
    return _checked(text, params_from, check_params)


def check_options(ap: argparse.ArgumentParser, args: argparse.Namespace, *,
                  cases: Iterable[str] | None = None, data: Iterable[str] = (),
                  image: tuple[int, int] | None = None, frames: int | None = None) -> None:
    """What the options decide together, checked before any work; ``ap.error`` on a fault.

    Args:
      ap, args: the parser and what it read; ``args.config`` / ``args.set`` (NAME=VALUE
        lists) and ``args.only`` (case names) are checked where the script has them.
      cases: every case name ``--only`` may name.
      data: folders the script reads under the data root (``$JAXVO_DATA``).
      image: (height, width) of the frames the settings run on, when known: the settings
        are checked at that size, and the run's memory (``frames`` of them) against the
        machine's.
    """
    from jaxvo.host.services.memory import check_memory, run_bytes

    only = getattr(args, "only", None)
    if only and cases is not None:
        known = list(cases)
        unknown = [n for n in only if n not in known]
        if unknown:
            ap.error(f"argument --only: no case {', '.join(map(repr, unknown))} (the cases: "
                     f"{', '.join(known)})")
    root = data_root()
    for name in data:
        if not (root / name).is_dir():
            ap.error(f"no {name} under the data root {root}: set JAXVO_DATA to the folder "
                     "that holds it")
    if getattr(args, "config", None):
        try:
            cfg = config_from(args.config)
            height, width = image or (None, None)
            check_config(cfg, height=height, width=width)
            if image is not None:
                check_memory(run_bytes(cfg, height=height, width=width, frames=frames or 0),
                             what=f"a run with {' '.join(args.config)}")
        except InputError as e:
            ap.error(f"argument --config: {e}")
    if getattr(args, "set", None):
        try:
            check_params(params_from(args.set))
        except InputError as e:
            ap.error(f"argument --set: {e}")
