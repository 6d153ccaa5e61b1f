"""A study on its devices (host side): the processes, the batch, the compiled programs
and the calls.

Numbers do not depend on how many devices or processes share the work: each process
compiles one program for all its devices (:func:`compiled_program`: ``shard_map`` over
them, each device vmapping the same ``batch`` consecutive configurations with no
communication between devices, so every device runs what one device alone would; no XLA
flag), on calls padded to a whole number of configurations per device (the padding is
dropped). The same configuration vmapped in a batch of another size may differ in the last
bit of a float, so the batch, not the device count, is what a study's bits depend on.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable
from typing import Any

import numpy as np

from jaxvo.config import Config, Params, StepOptions, grid_shape
from jaxvo.errors import InputError
from jaxvo.study.data import SequenceData


def batched_params(configs: list[dict]):
    """``Params`` of numpy float32 (B,) arrays, one entry per configuration."""
    from jaxvo.core.pipeline import batch_params

    sweeps = {f: [c.get(f, getattr(Params(), f)) for c in configs] for f in Params._fields}
    return Params(*(np.asarray(a) for a in batch_params(Params(), **sweeps)))


# Configurations per device and call on the CPU: a vmapped call is no faster per
# configuration than one scan there (docs/report/study.md: a 32-configuration study at 4
# ran 0.89x the best batch), so small calls keep the padding and the resume granularity
# small. Accelerators size theirs from the device and the study (accelerator_batch).
CPU_BATCH = 4


# The largest share of a device's free memory one call may take, and the widest call. An
# accelerator's throughput grew with the call's width as far as it was measured
# (docs/report/host_decisions.md): it wants the widest call the study and the memory allow.
MEMORY_SHARE = 0.5
MAX_ACCELERATOR_BATCH = 16384


def accelerator_batch(configs_per_device: int, bytes_per_config: float | None,
                      free_bytes: float | None) -> int:
    """Configurations per device and call on an accelerator: every configuration of the
    study in one call (a power of two at or above it, so that studies of nearby sizes share
    a compiled program), no wider than :data:`MEMORY_SHARE` of the free memory at
    ``bytes_per_config`` allows.

    Args:
      configs_per_device: the study's runs of one program, divided over the devices.
      bytes_per_config: device memory one configuration of the call needs (the compiled
        program's arguments, outputs and temporaries over its batch), None when unknown.
      free_bytes: the device's free memory, None when it does not say.
    """
    batch = 1 << max(0, int(configs_per_device) - 1).bit_length()
    batch = min(batch, MAX_ACCELERATOR_BATCH)
    if bytes_per_config and free_bytes:
        fits = int(MEMORY_SHARE * free_bytes // bytes_per_config)
        while batch > 1 and batch > fits:
            batch //= 2
    return batch


def free_memory(device) -> float | None:
    """Bytes free on ``device`` (None where its backend keeps no statistics, as the CPU)."""
    try:
        stats = device.memory_stats()
    except Exception:  # noqa: BLE001 - backends without statistics raise or return None
        return None
    if not stats or "bytes_limit" not in stats:
        return None
    return float(stats["bytes_limit"] - stats.get("bytes_in_use", 0))


# How long the processes of a study wait for each other to join, seconds (JAX's own
# default); past it each stops with one line (JAX itself aborted the process, exit 134 with
# a native stack trace, after 300 s of silence)
JOIN_TIMEOUT = 300.0


def init_distributed(coordinator: str | None, num_processes: int | None,
                     process_id: int | None, *, timeout: float = JOIN_TIMEOUT,
                     say: Callable[[str], None] | None = None) -> None:
    """Join a multi-process study (``jax.distributed``) when more than one process is
    asked for; call before JAX touches a device.

    The processes first meet on the coordinator's port (:func:`join`: each says so on
    ``say`` while it waits, and stops with one line after ``timeout`` seconds when one is
    missing), then start JAX's distributed runtime. On the CPU the processes exchange data
    over Gloo (JAX's default CPU collectives).

    Raises:
      InputError: a missing coordinator or process id, an id out of range, or processes
        that did not all join within ``timeout``.
    """
    if not num_processes or num_processes == 1:
        return
    if coordinator is None or process_id is None:
        raise InputError("a study over several processes needs the coordinator (HOST:PORT) "
                         "and this process's id (0 .. num_processes - 1)")
    if not 0 <= process_id < num_processes:
        raise InputError(f"process id {process_id} is not in 0 .. {num_processes - 1}")
    join(coordinator, num_processes, process_id, timeout=timeout, say=say)
    import jax

    if jax.config.jax_cpu_collectives_implementation is None:  # JAX before 0.5 had none
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(coordinator_address=coordinator, num_processes=num_processes,
                               process_id=process_id,
                               initialization_timeout=max(int(timeout), 1))


_HELLO = "jaxvo-study-join"


def join(coordinator: str, num_processes: int, process_id: int, *, timeout: float,
         say: Callable[[str], None] | None = None) -> None:
    """Wait until every process of a study is there, on the coordinator's own port (which
    JAX's runtime takes over afterwards): process 0 listens and tells each other process to
    go once all ``num_processes`` have come, or why not; the others call it until it
    answers. Each says on ``say`` that it waits, and for whom.

    Raises:
      InputError: one line, after ``timeout`` seconds without every process (naming the
        missing ones), or when process 0 refused this one (another count, a taken id).
    """
    import socket
    import time

    host, _, port_text = coordinator.rpartition(":")
    host = host.strip("[]")
    if not host or not port_text.isdigit():
        raise InputError(f"--coordinator must be HOST:PORT, got {coordinator!r}")
    port = int(port_text)
    deadline = time.monotonic() + timeout
    tell = say or (lambda line: None)
    how = (f"start each with the same spec, --coordinator {coordinator}, --num-processes "
           f"{num_processes} and its own --process-id")
    if process_id == 0:
        tell(f"jaxvo study: process 0 of {num_processes}: waiting up to {timeout:g} s for the "
             f"other {num_processes - 1} at {coordinator}")
        _meet(coordinator, port, num_processes, deadline, timeout=timeout, how=how)
        return
    said = False
    while True:
        try:
            conn = socket.create_connection((host, port), timeout=1.0)
            break
        except OSError:
            if not said:
                tell(f"jaxvo study: process {process_id} of {num_processes}: waiting up to "
                     f"{timeout:g} s for process 0 at {coordinator}")
                said = True
            if time.monotonic() > deadline:
                raise InputError(f"--coordinator {coordinator}: process 0 did not answer "
                                 f"within {timeout:g} s; {how}") from None
            time.sleep(0.5)
    with conn:
        conn.settimeout(max(deadline - time.monotonic(), 0.01))
        try:
            conn.sendall(f"{_HELLO} {process_id} {num_processes}\n".encode())
            answer = conn.makefile().readline().strip()
        except OSError:
            answer = ""
    if answer != "go":
        why = answer[3:] if answer.startswith("no ") else "no answer"
        raise InputError(f"the first process stopped the study ({why}); {how}")


def _meet(coordinator: str, port: int, num_processes: int, deadline: float, *,
            timeout: float, how: str) -> None:
    """Process 0's side of :func:`join`: listen until every other process has said hello,
    then tell them all to go (or, past ``deadline``, why not)."""
    import socket
    import time

    family = socket.AF_INET6 if ":" in coordinator.rpartition(":")[0] else socket.AF_INET
    with socket.socket(family) as server:
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            server.bind(("", port))
        except OSError as exc:
            raise InputError(f"--coordinator {coordinator}: cannot listen on port {port} "
                             f"({exc.strerror})") from None
        server.listen(num_processes)
        joined: dict[int, socket.socket] = {}
        try:
            while len(joined) < num_processes - 1:
                server.settimeout(max(deadline - time.monotonic(), 0.01))
                try:
                    conn, _ = server.accept()
                except TimeoutError:
                    missing = sorted(set(range(1, num_processes)) - set(joined))
                    for c in joined.values():
                        _send(c, f"no process(es) {missing} did not join")
                    raise InputError(
                        f"--num-processes {num_processes}: process(es) "
                        f"{', '.join(map(str, missing))} did not join at {coordinator} within "
                        f"{timeout:g} s; {how}") from None
                other = _hello(conn, num_processes, joined)
                if other is not None:
                    joined[other] = conn
            for c in joined.values():
                _send(c, "go")
        finally:
            for c in joined.values():
                c.close()


def _hello(conn, num_processes: int, joined: dict) -> int | None:
    """The process id a joining process sends, or None (told why, and closed)."""
    conn.settimeout(5.0)
    try:
        parts = conn.makefile().readline().split()
    except OSError:
        parts = []
    if len(parts) != 3 or parts[0] != _HELLO or not parts[1].isdigit():
        conn.close()  # not a process of a study (a port scan, another program)
        return None
    pid, count = int(parts[1]), parts[2]
    why = (f"--num-processes {count} here, {num_processes} on process 0"
           if count != str(num_processes) else
           f"process id {pid} is taken" if pid in joined or not 0 < pid < num_processes
           else None)
    if why is not None:
        _send(conn, f"no {why}")
        conn.close()
        return None
    return pid


def _send(conn, line: str) -> None:
    with contextlib.suppress(OSError):
        conn.sendall((line + "\n").encode())


def study_devices() -> list:
    """Every device of every process, in the order the configurations are dealt out:
    process by process, each process's own devices in JAX's order."""
    import jax

    return sorted(jax.devices(), key=lambda d: (d.process_index, d.id))


# the name of the mesh axis a call's configurations are split along, one block a device
DEVICES_AXIS = "devices"


@functools.cache
def _study_program(cfg: StepOptions, grid: tuple[int, int], devices: tuple):
    """``run_study`` of a block of configurations on each of ``devices`` as one program
    (``shard_map``: each device vmaps its own block, with no communication between them, so
    each computes what it would alone); jitted, with its mesh. The program returns
    ``(T_w_c, moving, status)`` stacked over every device's configurations in turn, the
    poses as the committed chain has them at the end
    (:func:`jaxvo.core.pipeline.committed_poses`)."""
    import jax
    from jax.sharding import Mesh
    from jax.sharding import PartitionSpec as P

    from jaxvo.core.pipeline import committed_poses, run_study

    def one_device(flows, keyframes, T_w_c0, seeds, params):
        keys = jax.vmap(jax.random.key)(seeds)
        out = run_study(flows, keys, params, T_w_c0, cfg=cfg, grid=grid, keyframes=keyframes)
        poses = jax.vmap(committed_poses)(out)
        return poses, out.moving, out.status

    mesh = Mesh(np.asarray(devices, dtype=object), (DEVICES_AXIS,))
    program = jax.shard_map(
        one_device, mesh=mesh, out_specs=P(DEVICES_AXIS),
        in_specs=(P(), P(), P(), P(DEVICES_AXIS), P(DEVICES_AXIS)),
        check_vma=False)  # no collective over the devices: nothing to check
    return jax.jit(program), mesh


def _call_args(data: SequenceData, configs: list[dict], seeds: np.ndarray):
    """The host arguments of a call: the flow (and the keyframe flow, None without
    keyframes) and the start pose, which every device reads, and the seeds and the
    configurations' ``Params``, one block of ``batch`` a device."""
    return (data.flows, data.keyframes, data.T_w_c0.astype(np.float32), seeds,
            batched_params(configs))


def _shardings(args, mesh) -> tuple:
    """Where each of a call's arguments lives (:func:`_call_args`): the flows and the start
    pose on every device of ``mesh``, the seeds and the ``Params`` a block a device."""
    import jax
    from jax.sharding import NamedSharding
    from jax.sharding import PartitionSpec as P

    whole, split = NamedSharding(mesh, P()), NamedSharding(mesh, P(DEVICES_AXIS))
    flows, keyframes, T_w_c0, seeds, params = args
    return (*jax.tree.map(lambda _: whole, (flows, keyframes, T_w_c0)),
            jax.tree.map(lambda _: split, seeds), jax.tree.map(lambda _: split, params))


_compiled: dict[tuple, Any] = {}


def compiled_program(cfg: Config, grid: tuple[int, int], args, devices):
    """The study program for ``devices`` (this process's), compiled once for all of them
    (one ``shard_map`` program: the same computation on each device's block; the tests
    hold 4 devices and 2 processes to one device's bits. It used to be compiled once per
    device, the device being part of the compile's key on the CPU), loaded from the
    persistent compile cache where it is there. ``args``: the call's host arguments (:func:`_call_args`), ``batch``
    configurations a device.

    Returns:
      ``(executable, shardings)``: the compiled program and where its arguments go.
    """
    import jax

    devices = tuple(devices)
    fn, mesh = _study_program(cfg.step, grid, devices)  # a flow setting compiles nothing
    shardings = _shardings(args, mesh)
    shapes = jax.tree.map(lambda a: (np.shape(a), np.asarray(a).dtype), args)
    key = (cfg.step, grid, str(shapes), devices)
    if key not in _compiled:
        _compiled[key] = fn.lower(*jax.tree.map(
            lambda a, where: jax.ShapeDtypeStruct(np.shape(a), np.asarray(a).dtype,
                                                  sharding=where), args, shardings)).compile()
    return _compiled[key], shardings


def bytes_per_config(executable, batch: int) -> float | None:
    """Device memory one configuration of a compiled call needs (its arguments, outputs and
    temporaries over the batch); None where the backend does not say."""
    try:
        m = executable.memory_analysis()
    except Exception:  # noqa: BLE001 - not every backend analyses memory
        return None
    if m is None:
        return None
    total = (m.argument_size_in_bytes + m.output_size_in_bytes + m.temp_size_in_bytes
             - m.alias_size_in_bytes)
    return total / batch


def call_batch(data: SequenceData, cfg: Config, configs: list[dict], *, requested: int | None,
               devices: list) -> int:
    """Configurations per device and call for ``configs`` of one program: ``requested``
    (``--batch`` or the spec's) where given, 4 on the CPU, else the accelerator's widest
    call that the study fills and half its free memory holds (compiled at that width to
    read its memory need, then halved until it fits)."""
    if requested:
        return requested
    if devices[0].platform == "cpu":
        return CPU_BATCH
    import jax

    own = next(d for d in devices if d.process_index == jax.process_index())
    per_device = -(-len(configs) // len(devices))
    free = free_memory(own)
    batch = accelerator_batch(per_device, None, free)
    grid = grid_shape(data.height, data.width, cfg.cell)
    while True:
        args = _call_args(data, [configs[0]] * batch, np.zeros(batch, np.uint32))
        need = bytes_per_config(compiled_program(cfg, grid, args, [own])[0], batch)
        fits = accelerator_batch(per_device, need, free)
        if fits >= batch:
            break
        batch = fits
    return int(from_first(np.asarray([batch]))[0])  # every process calls alike


def _gather(local: np.ndarray) -> np.ndarray:
    """Every process's block of results, in process order, on every process."""
    import jax

    if jax.process_count() == 1:
        return local
    from jax.experimental import multihost_utils

    return np.asarray(multihost_utils.process_allgather(local, tiled=True))


def run_call(data: SequenceData, cfg: Config, configs: list[dict], seeds: list[int], *,
             devices: list, batch: int):
    """One call: configuration ``i`` with seed ``seeds[i]`` on ``data``'s flow.

    The list is padded with copies of its last entry to ``batch`` times the device count
    (the padding's results are dropped) and dealt out in order, ``batch`` consecutive
    configurations to each device of :func:`study_devices`; each process runs one program
    over its devices (:func:`compiled_program`), so its devices work at once.

    Returns:
      ``(T_w_c (B, T, 4, 4) float32, moving (B, T, n) bool, status (B, T) int32)`` numpy.
    """
    import jax

    size = batch * len(devices)
    b = len(configs)
    if not 0 < b <= size or len(seeds) != b:
        raise ValueError(f"a call takes 1 to {size} configurations with one seed each, got "
                         f"{b} and {len(seeds)} seeds")
    configs = list(configs) + [configs[-1]] * (size - b)
    seeds = np.asarray(list(seeds) + [seeds[-1]] * (size - b), np.uint32)
    # this process's devices, consecutive in study_devices()'s order: their blocks in turn
    mine = [k for k, d in enumerate(devices) if d.process_index == jax.process_index()]
    lo, hi = mine[0] * batch, (mine[-1] + 1) * batch
    args = _call_args(data, configs[lo:hi], seeds[lo:hi])
    grid = grid_shape(data.height, data.width, cfg.cell)
    program, shardings = compiled_program(cfg, grid, args, [devices[k] for k in mine])
    outs = program(*jax.device_put(args, shardings))
    return tuple(_gather(np.asarray(o))[:b] for o in outs)


def from_first(x: np.ndarray) -> np.ndarray:
    """The first process's value of ``x`` on every process (the same shape everywhere)."""
    import jax

    if jax.process_count() == 1:
        return x
    from jax.experimental import multihost_utils

    return np.asarray(multihost_utils.broadcast_one_to_all(x))


def agree(problem: InputError | None) -> None:
    """Raise the first process's ``problem`` on every process (the others would otherwise
    wait for it in the next exchange until JAX's timeout)."""
    if from_first(np.asarray([problem is not None]))[0]:
        raise problem or InputError("the first process stopped the study; see its message")


def share_data(data: SequenceData | None, cfg: Config) -> SequenceData:
    """The first process's flow (and, with ``cfg.keyframes``, keyframe flow) on every
    process: the others need neither the frames nor the cache, and every device computes on
    the same flow."""
    import jax

    if jax.process_count() == 1:
        return data
    head = np.zeros(4, np.int64)
    if data is not None:
        T, n = data.flows.valid.shape
        head[:] = (T, n, data.height, data.width)
    T, n, h, w = (int(v) for v in from_first(head))
    if data is None:
        data = receiving_data(T, n, h, w, cfg)
    T0 = from_first(np.asarray(data.T_w_c0, np.float64))
    return data._replace(flows=_from_first_tree(data.flows),
                         keyframes=_from_first_tree(data.keyframes), T_w_c0=T0)


def receiving_data(pairs: int, n: int, height: int, width: int, cfg: Config) -> SequenceData:
    """What a process other than the first holds before the first's flow arrives
    (:func:`share_data`): arrays of the shapes and types of the first's, ``pairs`` frame
    pairs of ``n`` grid points (the keyframe flow with ``cfg.keyframes``), all invalid."""
    from jaxvo.core.inputs import invalid_flow, invalid_keyframe_flow, stack_flows

    flows = stack_flows([invalid_flow(np.zeros((n, 2)))] * pairs)
    kf = (stack_flows([invalid_keyframe_flow(n, cfg.keyframe_window)] * pairs)
          if cfg.keyframes else None)
    return SequenceData("", flows, kf, np.eye(4), np.zeros(pairs + 1), None, None, height,
                        width)


def _from_first_tree(tree):
    """Every array of a NamedTuple of arrays (or None) as the first process has it."""
    return None if tree is None else type(tree)(*(from_first(np.asarray(a)) for a in tree))
