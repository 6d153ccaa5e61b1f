"""Where the test suite's time goes: every program XLA compiles in the tests' processes,
with the test that compiled it and how long it took.

A pytest plugin. Load it with ``-p`` from the repository root, on a cold compile cache (a
fresh clone, or ``--cache-clear``), as CI runs the suite::

    PYTHONPATH=bench pytest -q -n 2 --dist worksteal -p suite_compiles --cache-clear

Each process of the session (each xdist worker) writes its compiles as JSON lines to
``results/suite_compiles/<worker>.jsonl``: the test's id, the program's name, its key in
the persistent compile cache (equal keys: the same program compiled twice), the seconds
XLA took. Compiles in the tests' child processes (``jaxvo`` commands, examples, studies on
several devices) are not seen: their time shows in the test's duration only. Then::

    python bench/suite_compiles.py [--over 3]

prints the programs that took over ``--over`` seconds, by test, the total, and how many
were compiled more than once. It reads a private function of JAX
(``jax._src.compiler._compile_and_write_cache``, JAX 0.10): where that is gone it says so
and records nothing.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import time
from pathlib import Path

OUT = Path("results/suite_compiles")

_current: dict[str, str | None] = {"test": None}
_records: list[dict] = []


def pytest_configure(config):
    try:
        from jax._src import compiler

        compile_and_write = compiler._compile_and_write_cache
    except (ImportError, AttributeError):
        print("suite_compiles: this JAX has no _compile_and_write_cache; nothing recorded")
        return

    def recorded(backend, computation, devices, options, callbacks, module_name, cache_key,
                 *rest, **kwargs):
        start = time.perf_counter()
        try:
            return compile_and_write(backend, computation, devices, options, callbacks,
                                     module_name, cache_key, *rest, **kwargs)
        finally:
            _records.append({"test": _current["test"], "program": module_name,
                             "key": cache_key[-16:], "seconds": time.perf_counter() - start})

    compiler._compile_and_write_cache = recorded


def pytest_runtest_logstart(nodeid, location):
    _current["test"] = nodeid


def pytest_runtest_logfinish(nodeid, location):
    _current["test"] = None


def pytest_unconfigure(config):
    OUT.mkdir(parents=True, exist_ok=True)
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    with open(OUT / f"{worker}.jsonl", "w") as f:
        f.writelines(json.dumps(r) + "\n" for r in _records)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--over", type=float, default=3.0, help="seconds (default 3)")
    parser.add_argument("--folder", type=Path, default=OUT)
    args = parser.parse_args()
    rows = [json.loads(line) for path in sorted(args.folder.glob("*.jsonl"))
            for line in path.read_text().splitlines()]
    if not rows:
        raise SystemExit(f"suite_compiles: no records under {args.folder}")
    big = sorted((r for r in rows if r["seconds"] > args.over), key=lambda r: -r["seconds"])
    for r in big:
        print(f"{r['seconds']:6.1f} s  {r['program']:<22} {r['key']}  {r['test']}")
    keys = collections.Counter(r["key"] for r in big)
    print(f"{len(rows)} compiles, {sum(r['seconds'] for r in rows):.0f} s in all; "
          f"{len(big)} over {args.over:g} s, {sum(r['seconds'] for r in big):.0f} s; "
          f"{sum(n - 1 for n in keys.values())} of them compiled again")


if __name__ == "__main__":
    main()
