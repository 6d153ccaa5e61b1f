"""``jaxvo study SPEC --out DIR``: a study over sequences, settings and seeds.

The spec (TOML or JSON; see docs/study.md) names sequences, ``Params`` and
``Config`` values and seeds. Each sequence's flow is computed once and cached; the
configurations run as vmapped whole-sequence scans split over every device; every run is
scored and kept as soon as its call finishes, so an interrupted study continues with
``--resume``. Several processes (on one machine or several) share a study when each is
started with the same spec and ``--coordinator``, ``--num-processes`` and its own
``--process-id``; the first one reads the data and writes the results.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = __doc__.split("\n\n", 1)[1].replace("``", "")
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = (
        "files written under --out:\n"
        "  results.csv, results.json         one row per run\n"
        "  summary.csv, summary.json, .md    mean and spread over seeds\n"
        "  plot.png                          each metric against each swept setting "
        "(needs matplotlib)\n"
        "  runs.jsonl                        finished runs, read by --resume\n"
        "  spec.json, flows/                 the parsed spec, the flow cache\n\n"
        "several machines: start on every machine, each with its own --process-id,\n"
        "  jaxvo study SPEC --out DIR --coordinator HOST0:12345 --num-processes N "
        "--process-id I\n"
        "HOST0:12345 is reachable from every machine (process 0 listens there);\n"
        "only process 0 needs the sequences and writes DIR."
    )
    p.add_argument("spec", metavar="SPEC", help="study spec, .toml or .json")
    p.add_argument("--out", "-o", required=True, metavar="DIR", help="results folder (created)")
    p.add_argument("--resume", action="store_true",
                   help="continue the study in DIR: run only what it has not finished")
    p.add_argument("--flow-cache", metavar="DIR",
                   help="where flows are cached (default DIR/flows); studies may share one")
    p.add_argument("--batch", type=int, metavar="N",
                   help="configurations per device and call (default: the spec's, else 4 on "
                   "the CPU; on an accelerator the widest call the study fills and half the "
                   "free memory holds)")
    p.add_argument("--cpu-devices", type=int, metavar="N",
                   help="split the CPU into N JAX devices (to shard a study on the CPU)")
    p.add_argument("--coordinator", metavar="HOST:PORT",
                   help="address of process 0, for a study over several processes")
    p.add_argument("--num-processes", type=int, metavar="N", help="processes in the study")
    p.add_argument("--process-id", type=int, metavar="I", help="this process, 0 .. N - 1")
    p.add_argument("--join-timeout", type=float, default=300.0, metavar="S",
                   help="how long the processes wait for each other to join, seconds (default "
                   "300); each says that it waits, and stops with one line past it")
    p.add_argument("--no-plot", action="store_true", help="skip plot.png")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress line")


def run(args: argparse.Namespace, prepared=None) -> int:
    import time

    from jaxvo.cli.main import interrupt_at_safe_points, quiet_interrupts_at_exit
    from jaxvo.host.services.progress import Progress
    from jaxvo.study import runner as study
    from jaxvo.study.report import write_report

    spec, first = _start(args, prepared or prepare(args))
    quiet_interrupts_at_exit()  # JAX is loaded: its clean-up at exit is no place for a traceback
    quiet = args.quiet or args.json or not first
    progress = Progress("jaxvo study", enabled=not quiet, unit="config-frames")
    start = time.perf_counter()
    # main()'s request, where main() runs the command: a Ctrl-C stops after the current call
    with interrupt_at_safe_points() as stop:
        try:
            res = study.run_spec(spec, args.out, resume=args.resume,
                                 flow_cache=args.flow_cache, batch=args.batch,
                                 progress=progress, log=progress.note, stop=stop)
            stop()  # a Ctrl-C in the last call: the study was interrupted all the same
        except KeyboardInterrupt:
            progress.close()
            if first and (Path(args.out) / study.RUNS_FILE).is_file():
                rows = study.finished_rows(spec, args.out)
                write_report(spec, rows, args.out, plot=not args.no_plot)
                print(f"jaxvo: interrupted: {len(rows)} finished runs kept in {args.out}; "
                      "continue with --resume", file=sys.stderr)
            raise
    progress.close()
    if not first:
        return 0
    files = write_report(spec, res.rows, args.out, plot=not args.no_plot)
    summary = _summary(args, spec, res, files, time.perf_counter() - start)
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        _print_summary(args, spec, res, summary)
    return 0


def prepare(args: argparse.Namespace):
    """The options checked and the spec read, before JAX loads (a multi-process study must
    join before it starts): ``(spec, coordinator, processes, process id)`` for :func:`run`.
    :mod:`jaxvo.study.spec` reads it without NumPy: a spec that is not there, or not TOML
    or JSON, is answered before NumPy loads."""
    from jaxvo.errors import InputError
    from jaxvo.study.spec import load_spec

    if args.batch is not None and args.batch < 1:
        raise InputError(f"--batch must be at least 1, got {args.batch}")
    if not (args.join_timeout > 0 and args.join_timeout < float("inf")):
        raise InputError(f"--join-timeout must be a positive number of seconds, got "
                         f"{args.join_timeout}")
    _check_cpu_devices(args.cpu_devices)
    spec = load_spec(args.spec, check_folders=False)
    dist = spec.distributed
    coordinator = args.coordinator or dist.get("coordinator")
    nproc = args.num_processes if args.num_processes is not None else dist.get("num_processes")
    pid = args.process_id if args.process_id is not None else dist.get("process_id")
    if not pid:  # the first process (or the only one) reads the sequences: they must exist
        spec = load_spec(args.spec)
    return spec, coordinator, nproc, pid


def _start(args: argparse.Namespace, prepared):
    """The devices set up and the processes joined; returns ``(spec, this is the first
    process)``."""
    import jax

    from jaxvo.study import runner as study

    spec, coordinator, nproc, pid = prepared

    if args.cpu_devices is not None:
        jax.config.update("jax_num_cpu_devices", args.cpu_devices)
    study.init_distributed(coordinator, nproc, pid, timeout=args.join_timeout,
                           say=lambda line: print(line, file=sys.stderr, flush=True))
    return spec, jax.process_index() == 0


def _check_cpu_devices(n: int | None) -> None:
    """Refuse a --cpu-devices count beyond this machine's cores (InputError): each device
    compiles its own program and runs on its own thread, so past the cores it only adds
    compiles (a thousand of them made a 3-frame study compile for minutes, in many times
    the memory)."""
    import os

    from jaxvo.errors import InputError

    if n is None:
        return
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    if not 1 <= n <= (cores or 1):
        raise InputError(f"--cpu-devices must be 1 to {cores or 1} (this machine's cores: more "
                         f"devices only add compiles), got {n}")


def _summary(args: argparse.Namespace, spec, res, files: dict, took: float) -> dict:
    """What the study did, as the ``--json`` summary holds it."""
    steady_frames = res.config_frames - res.first_call_frames
    steady_s = res.seconds - res.first_call_seconds
    rate = steady_frames / steady_s if steady_s > 0 else None
    return {
        "study": spec.name,
        "out": str(args.out),
        "runs": len(res.rows),
        "runs_in_spec": res.total,
        "runs_this_time": res.ran,
        "sequences": len(spec.sequences),
        "configurations": len(spec.configs),
        "seeds": len(spec.seeds),
        "devices": res.devices,
        "processes": res.processes,
        "batch_per_device": list(res.batch),
        "config_frames": res.config_frames,
        "config_frames_per_second": None if rate is None else round(rate, 1),
        "device_seconds": round(res.seconds, 2),
        "first_call_seconds": round(res.first_call_seconds, 2),
        "flow_seconds": round(res.flow_seconds, 2),
        "seconds": round(took, 2),
        "files": files,
    }


def _print_summary(args: argparse.Namespace, spec, res, summary: dict) -> None:
    print(f"jaxvo study: {spec.name}: {len(res.rows)} of {res.total} runs in {args.out} "
          f"({res.ran} this time; {len(spec.sequences)} sequences x {len(spec.configs)} "
          f"configurations x {len(spec.seeds)} seeds)")
    sized = "--batch" if args.batch else ("the spec" if spec.batch else
                                          "sized for the device and the study")
    batches = " / ".join(str(b) for b in res.batch) or "none (nothing left to run)"
    print(f"  devices    {res.devices} over {res.processes} process(es), {batches} "
          f"configurations per device and call ({sized})")
    rate = summary["config_frames_per_second"]
    speed = "n/a (every call compiled)" if rate is None else f"{rate:.1f} configuration-frames/s"
    print(f"  speed      {speed} after the first call of each program; first calls "
          f"(compile included) {res.first_call_seconds:.1f} s, flow {res.flow_seconds:.1f} s, "
          f"{summary['seconds']:.1f} s in all")
    for name, what in summary["files"].items():
        if what != "written":
            print(f"  {name:10s} skipped: {what}")
    table = (Path(args.out) / "summary.md").read_text().splitlines()
    if len(table) <= 40:
        print("\n".join(table[2:]))
