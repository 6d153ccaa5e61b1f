"""Studies: the spec and its one-line errors, the flow cache's key, sharded runs that give
the same bits on 1 device, 4 devices and 2 processes, resuming, and the tables."""

from __future__ import annotations

import csv
import json
import os
import socket
import subprocess
import sys
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import python_code

from jaxvo.cli.main import main
from jaxvo.config import Config, Params
from jaxvo.core.pipeline import batch_params, run_study
from jaxvo.errors import InputError
from jaxvo.evaluation.scores import trajectory_scores
from jaxvo.study import runner as study
from jaxvo.study.report import plot_points, summarise, write_report
from jaxvo.trajectory import Trajectory

# a tiny study: 8 frames of the fast hand-held scene, a coarse grid, few hypotheses, a
# confidence of 0.9 and the online noise calibration on (at the defaults the runs of lam 10
# and 1000 and of both seeds gave the same bits, 2 digests of 6; here 5), so that the runs
# differ by seed and setting and a run out of place shows
TINY = """
name = "tiny"
seeds = [0, 1]
batch = 1
[[sequences]]
scene = "handheld_fast"
frames = 8
[fixed]
cell = 32
num_hypotheses = 4
confidence = 0.9
noise_calibration = true
noise_rate = 0.2
[sweep]
lam = [10.0, 100000.0]
"""


def spec_of(text: str, tmp_path: Path, name: str = "spec.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def folder_spec(tmp_path: Path, folder: Path, *, seed: int, **fixed):
    """A parsed study of one sequence folder under one seed, in calls of one
    configuration, with the ``fixed`` settings."""
    settings = "\n".join(f"{k} = {json.dumps(v)}" for k, v in fixed.items())
    return study.load_spec(spec_of(f"""
name = "{folder.name}"
seeds = [{seed}]
batch = 1
[[sequences]]
path = "{folder}"
[fixed]
{settings}
""", tmp_path))


# ----------------------------------------------------------------------------- the spec


def test_sweep_grid_and_points_make_the_configurations_in_order(tmp_path):
    spec = study.load_spec(spec_of("""
seeds = 3
[[sequences]]
scene = "static"
[fixed]
delta = 0.05
[grid]
num_hypotheses = [10, 20]
[sweep]
lam = [100.0, 1000.0]
[[points]]
max_age = 5
""", tmp_path))
    assert spec.seeds == (3,)
    # Config fields first, then Params fields, each in its class's order
    assert spec.settings == ("num_hypotheses", "lam", "delta", "max_age")
    assert spec.base == {"num_hypotheses": 20, "lam": 1e3, "delta": 0.05, "max_age": 15.0}
    got = [(c["num_hypotheses"], c["lam"], c["max_age"]) for c in spec.configs]
    # each grid point, then the sweep around it (lam 1000 is the base: not repeated), then
    # the points
    assert got == [(10, 1e3, 15.0), (10, 100.0, 15.0), (20, 1e3, 15.0), (20, 100.0, 15.0),
                   (20, 1e3, 5.0)]
    assert spec.swept == ("num_hypotheses", "lam", "max_age")
    assert all(c["delta"] == 0.05 for c in spec.configs)
    assert spec.sequences[0].label == "static_s0" and spec.metrics == study.DEFAULT_METRICS


def test_json_specs_and_folders_under_the_data_root(tmp_path, require_data):
    require_data("7scenes_static_0000_0299", "associations.txt")
    spec = study.load_spec(spec_of(json.dumps({
        "sequences": [{"path": "7scenes_static_0000_0299", "frames": 10, "step": 4},
                      {"composite": "7scenes_static_0000_0299", "scene": "handheld_slow"}],
    }), tmp_path, "s.json"))
    folder, comp = spec.sequences
    assert Path(folder.path).is_dir() and folder.label == "7scenes_static_0000_0299_every4"
    assert comp.label == "composite_handheld_slow_7scenes_static_0000_0299_s0"
    assert len(spec.configs) == 1 and spec.swept == ()


BAD = [
    ("colour = 1", "colour: unknown key"),
    ("seeds = [1, 1]", "seeds: repeats a seed"),
    ("seeds = [-1]", "seeds: must be an integer in 0 .. 2^31 - 1"),
    ("seeds = [2147483648]", "seeds: must be an integer in 0 .. 2^31 - 1"),
    ("metrics = ['ate']", "metrics: unknown metric 'ate'"),
    ("batch = 0", "batch: must be a positive integer"),
    ("[grid]\nlamda = [1.0, 2.0]", "grid.lamda: unknown setting"),
    ("[sweep]\nlam = []", "sweep.lam: is an empty list"),
    ("[sweep]\nlam = ['big']", "sweep.lam: a Params value must be a number"),
    ("[fixed]\nnum_hypotheses = 2.5", "fixed.num_hypotheses: a Config value of type int"),
    ("[fixed]\ndepth_smooth = 1", "fixed.depth_smooth: a Config value of type bool"),
    ("[fixed]\nmax_age = true", "fixed.max_age: a Params value must be a number"),
    ("[fixed]\nlam = 1.0\n[sweep]\nlam = [2.0]", "fixed.lam: is also swept"),
    ("[[points]]\nmax_age = 'old'", "points[0].max_age: a Params value must be a number"),
    # values outside a setting's range (they ran silently: nothing reported moving, NaN tests)
    ("[fixed]\nconfidence = 1.5", "fixed.confidence: the value must be in (0, 1), got 1.5"),
    ("[sweep]\nconfidence = [0.9, 1.0]", "sweep.confidence: the value must be in (0, 1), got 1"),
    ("[fixed]\nevidence_margin = -10.0", "fixed.evidence_margin: the value must be in [0, inf)"),
    ("[fixed]\nnoise_rate = -1", "fixed.noise_rate: the value must be in [0, 1], got -1"),
    ("[fixed]\nevidence_decay = 2.0", "fixed.evidence_decay: the value must be in [0, 1], got 2"),
    ("[fixed]\npixel_sigma = 0.0", "fixed.pixel_sigma: the value must be in (0, inf), got 0"),
    ("[fixed]\nlam = nan", "fixed.lam: the value must be a finite number"),
    # the consecutive-frame window is gone: a spec that sets it is told what replaced it
    ("[fixed]\nwindow = 5", ("fixed.window: the consecutive-frame window was removed; the "
                             "window over keyframes replaces it: keyframes = true, "
                             "keyframe_window")),
    ("[sweep]\nwindow_iters = [3]", ("sweep.window_iters: the consecutive-frame window was "
                                     "removed; the window over keyframes replaces it: "
                                     "keyframe_iters")),
    ("[distributed]\ncoordinator = 'nohost'", "distributed.coordinator: bad value"),
    # the sequences (a spec with its own [[sequences]] takes no default one)
    ("[[sequences]]\nscene = 'moon'", "sequences[0].scene: unknown scene 'moon'"),
    ("[[sequences]]\npath = 'no_such_folder_here'",
     "sequences[0].path: no folder 'no_such_folder_here'"),
    ("[[sequences]]\ncomposite = '.'", "sequences[0].scene: a composite needs the scene"),
    ("[[sequences]]\nscene = 'static'\nframes = 1",
     "sequences[0].frames: must be an integer >= 2"),
    ("[[sequences]]\nscene = 'static'\ncamera = 'tum_fr1'", "sequences[0].camera: only a folder"),
    ("[[sequences]]\nscene = 'static'\nfps = 10", "sequences[0].fps: unknown key"),
    ("[[sequences]]\nframes = 5", "sequences[0]: needs scene (a built-in scene), path"),
]


@pytest.mark.parametrize("extra, message", BAD)
def test_bad_specs_name_the_key_and_the_fault(tmp_path, extra, message):
    seq = '' if "[[sequences]]" in extra else '[[sequences]]\nscene = "static"\n'
    # TOML: top-level keys before the first table
    path = spec_of(seq + extra if extra.startswith("[") else extra + "\n" + seq, tmp_path)
    with pytest.raises(InputError) as err:
        study.load_spec(path)
    text = str(err.value)
    assert message in text and "\n" not in text and text.startswith(str(path))


def test_a_grid_of_100000_configurations_parses_in_seconds():
    """5 settings x 10 values: the configurations were deduplicated by scanning those kept
    (O(n^2)), silent for over 150 s; now a dict, in order, about 2 s on a loaded 2-core
    machine."""
    import time

    values = [round(0.05 * (i + 1), 2) for i in range(10)]
    grid = {k: values for k in ("lam", "delta", "confidence", "pixel_sigma", "depth_coeff")}
    t0 = time.perf_counter()
    spec = study.parse_spec({"sequences": [{"scene": "static"}], "grid": grid,
                             "points": [{"lam": 0.05, "delta": 0.05, "confidence": 0.05,
                                         "pixel_sigma": 0.05, "depth_coeff": 0.05}]})
    took = time.perf_counter() - t0
    assert len(spec.configs) == 100_000  # the point repeats the first grid cell: kept once
    assert spec.configs[0]["lam"] == 0.05 and spec.configs[1]["depth_coeff"] == 0.1  # order
    assert took < 30, took  # seconds (the list scan: > 150)


def test_only_the_first_process_needs_the_folders(tmp_path):
    path = spec_of("[[sequences]]\npath = 'on_the_first_machine'\n", tmp_path)
    with pytest.raises(InputError, match="no folder 'on_the_first_machine'"):
        study.load_spec(path)
    spec = study.load_spec(path, check_folders=False)
    assert spec.sequences[0].path == "on_the_first_machine"


def test_two_sequences_with_one_name_are_refused(tmp_path):
    text = "[[sequences]]\nscene = 'static'\n[[sequences]]\nscene = 'static'\n"
    with pytest.raises(InputError, match=r"sequences\[1\]: its name 'static_s0' is that of "
                                         r"sequences\[0\]"):
        study.load_spec(spec_of(text, tmp_path))


def test_settings_are_checked_against_params_as_they_are_now(tmp_path, monkeypatch):
    """The spec follows Params' fields at run time: a renamed field is refused, a new one
    accepted, with no list to update."""

    class Renamed(NamedTuple):
        noise_sigma: float = 0.002
        max_age: float = 15.0

    from jaxvo.study import spec as study_spec  # where the spec reads Params

    monkeypatch.setattr(study_spec, "Params", Renamed)
    spec = study.load_spec(spec_of("[[sequences]]\nscene = 'static'\n[sweep]\n"
                                   "noise_sigma = [0.001, 0.004]\n", tmp_path))
    assert spec.swept == ("noise_sigma",) and spec.base["noise_sigma"] == 0.002
    with pytest.raises(InputError, match="sweep.lam: unknown setting; Params has "
                                         "noise_sigma, max_age"):
        study.load_spec(spec_of("[[sequences]]\nscene = 'static'\n[sweep]\nlam = [1.0]\n",
                                tmp_path))


def test_cli_bad_spec_is_one_line_and_exit_2(tmp_path, capsys):
    path = spec_of("[[sequences]]\nscene = 'static'\n[grid]\nH = [10, 20]\n", tmp_path)
    assert main(["study", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("jaxvo: error:") and "grid.H: unknown" in err[0]
    broken = spec_of("seeds = [0,\n", tmp_path, "broken.toml")
    assert main(["study", str(broken), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not valid TOML" in err[0]
    assert main(["study", str(tmp_path / "none.toml"), "--out", str(tmp_path / "o")]) == 2
    assert "cannot read the study spec" in capsys.readouterr().err


# ---------------------------------------------------------------------------- the runs


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """The tiny study run once in this process (one CPU device)."""
    root = tmp_path_factory.mktemp("study")
    path = spec_of(TINY, root)
    spec = study.load_spec(path)
    res = study.run_spec(spec, root / "one", flow_cache=root / "flows")
    return spec, path, root, res


def digests(out: Path) -> dict[tuple, str]:
    return {k: r["digest"] for k, r in _rows(out).items()}


def _rows(out: Path) -> dict[tuple, dict]:
    rows = json.loads((out / "results.json").read_text()) if (out / "results.json").is_file() \
        else list(study.read_runs(out / study.RUNS_FILE).values())
    return _rows_of(rows)


def _rows_of(rows: list[dict]) -> dict[tuple, dict]:
    return {(r["sequence"], r["lam"], r["seed"]): r for r in rows}


def test_a_study_run_matches_run_study_called_directly(tiny):
    spec, _, root, res = tiny
    assert res.total == res.ran == len(res.rows) == 6 and res.devices == 1
    assert res.config_frames == 6 * 7
    # the runs differ (else the comparisons below could not see a run out of place)
    assert len({r["digest"] for r in res.rows}) >= 4

    data, cached = study.sequence_data(spec.sequences[0], Config(cell=32), root / "flows")
    assert cached and data.truth.shape == (7, 15 * 20)
    cfg = Config(cell=32, num_hypotheses=4, noise_calibration=True)
    for row in (res.rows[1], res.rows[4]):  # lam 1000 seed 1, lam 1e5 seed 0
        out = run_study(jax.tree.map(jnp.asarray, data.flows), jax.random.key(row["seed"])[None],
                        batch_params(Params(confidence=0.9, noise_rate=0.2), lam=[row["lam"]]),
                        jnp.asarray(data.T_w_c0, jnp.float32), cfg=cfg.step, grid=(15, 20))
        T, moving, status = (np.asarray(a[0]) for a in (out.T_w_c, out.moving, out.status))
        direct = study.score_run(data, T, moving, status)
        assert direct["digest"] == row["digest"]
        poses = np.concatenate([data.T_w_c0[None], T.astype(np.float64)])
        ref = trajectory_scores(data.groundtruth, Trajectory(data.timestamps, poses))
        assert row["ate_rmse_m"] == pytest.approx(ref["ate_rmse_m"], rel=0, abs=0)
        truth, pred = data.truth, moving
        tp = np.sum(truth & pred)
        assert row["moving_recall"] == pytest.approx(tp / np.sum(truth), abs=1e-12)
        assert row["moving_precision"] == pytest.approx(tp / np.sum(pred), abs=1e-12)


def _env(**extra) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    return {**env, "JAX_PLATFORMS": "cpu", **extra}


def _cli(*args) -> list[str]:
    return [sys.executable, "-m", "jaxvo.cli.main", "study", *map(str, args)]


@pytest.fixture(scope="module")
def one_device(tiny):
    """The tiny study as ``jaxvo study`` on one CPU device (a fresh process)."""
    _, path, root, _ = tiny
    out = root / "one_device"
    done = subprocess.run(_cli(path, "--out", out, "--flow-cache", root / "flows", "--json"),
                          env=_env(), capture_output=True, text=True, timeout=600, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    assert json.loads(done.stdout)["devices"] == 1
    return out


@pytest.mark.slow  # fresh processes on 4 devices / 2 processes: 35-55 s
def test_four_devices_give_the_same_bits_as_one(tiny, one_device):
    _, path, root, _ = tiny
    out = root / "four"
    done = subprocess.run(
        _cli(path, "--out", out, "--flow-cache", root / "flows", "--json"),
        env=_env(XLA_FLAGS="--xla_force_host_platform_device_count=4"),
        capture_output=True, text=True, timeout=600, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    summary = json.loads(done.stdout)
    assert summary["devices"] == 4 and summary["runs"] == 6
    assert summary["flow_seconds"] == 0.0  # the flow came from the shared cache
    assert digests(out) == digests(one_device)
    assert len(set(digests(out).values())) >= 4  # the runs differ
    # and the same bits as this process's own run of the study
    assert digests(out) == {k: r["digest"] for k, r in
                            _rows_of(tiny[3].rows).items()}


def test_an_accelerator_call_is_as_wide_as_the_study_and_its_memory_allow():
    # every configuration in one call, rounded up to a power of two
    assert study.accelerator_batch(108, None, None) == 128
    assert study.accelerator_batch(4096, None, None) == 4096
    assert study.accelerator_batch(1, None, None) == 1
    assert study.accelerator_batch(10**6, None, None) == study.MAX_ACCELERATOR_BATCH
    # no wider than half the free memory holds
    assert study.accelerator_batch(4096, 40e6, 80e9) == 512  # 1000 fit: 512
    assert study.accelerator_batch(4096, 10e9, 8e9) == 1  # not even one: the narrowest
    assert study.free_memory(jax.devices("cpu")[0]) is None  # the CPU keeps no statistics


def test_a_study_sets_no_xla_flag():
    """Newer XLA aborts the process on a flag it does not know (issue 30: the study died
    at start on JAX 0.11 over ``--xla_cpu_use_fusion_emitters``); the same bits on any
    device count come from compiling one program per device instead."""
    import importlib
    import inspect
    import pkgutil

    import jaxvo.cli.study
    import jaxvo.study

    modules = [importlib.import_module(m.name)
               for m in pkgutil.iter_modules(jaxvo.study.__path__, "jaxvo.study.")]
    assert study in modules and len(modules) >= 5  # spec, data, devices, runner, report
    for module in (*modules, jaxvo.cli.study):
        assert "XLA_FLAGS" not in inspect.getsource(module), module.__name__


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _two_processes(path, out, root):
    """``jaxvo study`` as two processes on this machine: (return codes, outputs)."""
    port = _free_port()
    procs = [subprocess.Popen(
        _cli(path, "--out", out, "--flow-cache", root / "flows", "--json",
             "--coordinator", f"127.0.0.1:{port}", "--num-processes", 2, "--process-id", i),
        env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for i in (0, 1)]
    outs = [p.communicate(timeout=600) for p in procs]
    return [p.returncode for p in procs], outs


def test_importing_jaxvo_leaves_jax_distributed_possible():
    """``jax.distributed.initialize`` (``jaxvo study --coordinator``) must run before JAX
    starts its backend, so importing jaxvo's modules must not start it (a JAX array built
    at import in jaxvo.core.pipeline did, and every multi-process study stopped at once)."""
    import pkgutil

    import jaxvo

    modules = sorted(m.name for m in pkgutil.walk_packages(jaxvo.__path__, "jaxvo.")
                     if not m.name.endswith(".__main__"))  # `python -m jaxvo.cli.main` runs it
    code = (f"import importlib, jax\n"
            f"for m in {modules!r}: importlib.import_module(m)\n"
            f"jax.distributed.initialize('127.0.0.1:{_free_port()}', num_processes=1, "
            f"process_id=0)\n"
            f"jax.distributed.shutdown()\n")
    done = subprocess.run([sys.executable, "-c", code], env=_env(), capture_output=True,
                          text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr[-2000:]


@pytest.mark.slow  # fresh processes on 4 devices / 2 processes: 35-55 s
def test_two_processes_give_the_same_bits_as_one(tiny, one_device):
    _, path, root, _ = tiny
    out = root / "two"
    codes, outs = _two_processes(path, out, root)
    assert codes == [0, 0], [e[-2000:] for _, e in outs]
    # Gloo's C++ side prints its connection line to stdout
    printed = ["".join(ln for ln in o.splitlines(keepends=True) if not ln.startswith("[Gloo]"))
               for o, _ in outs]
    summary = json.loads(printed[0])
    assert summary["devices"] == 2 and summary["processes"] == 2
    assert printed[1] == ""  # only the first process reports
    assert digests(out) == digests(one_device)

    # a fault the first process finds stops both, each with one line
    codes, outs = _two_processes(path, out, root)
    assert codes == [2, 2]
    assert outs[0][1].strip().splitlines()[-1].endswith("or choose another --out")
    assert "the first process stopped the study" in outs[1][1]


def test_a_process_receives_the_flow_in_arrays_of_the_first_process_s_shapes(tmp_path):
    """The processes after the first receive the first's flow (and keyframe flow) into
    arrays they make themselves (``share_data``): each must have the shape and type of the
    first's, or the exchange fails or garbles it."""
    from jaxvo.study.devices import receiving_data

    for cfg in (Config(cell=32), Config(cell=32, keyframes=True)):
        data, _ = study.sequence_data(study.SequenceSpec("x", "handheld_fast", None, 3, 0, 1,
                                                         None), cfg, None)
        T, n = data.flows.valid.shape
        got = receiving_data(T, n, data.height, data.width, cfg)
        assert (got.keyframes is None) == (not cfg.keyframes)
        for mine, first in ((got.flows, data.flows), (got.keyframes, data.keyframes)):
            assert jax.tree.map(lambda a: (a.shape, a.dtype), mine) == \
                jax.tree.map(lambda a: (np.shape(a), np.asarray(a).dtype), first)


def test_an_interrupted_study_resumes_where_it_stopped(tiny, tmp_path):
    spec, _, root, first = tiny
    out = tmp_path / "resumed"
    calls = []

    def stop_after_two(done, total):
        calls.append(done)
        if len(calls) == 3:  # after the second call of one configuration each
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        study.run_spec(spec, out, flow_cache=root / "flows", progress=stop_after_two)
    kept = study.read_runs(out / study.RUNS_FILE)
    assert len(kept) == 2
    with (out / study.RUNS_FILE).open("a") as fh:
        fh.write('{"id": "cut sho')  # a line cut short by the interruption
    with pytest.raises(InputError, match="pass --resume"):
        study.run_spec(spec, out, flow_cache=root / "flows")
    res = study.run_spec(spec, out, resume=True, flow_cache=root / "flows")
    assert res.ran == 4 and len(res.rows) == 6
    assert [r["digest"] for r in res.rows] == [r["digest"] for r in first.rows]

    # a larger study in the same folder runs only what is new
    more = spec._replace(seeds=(0, 1, 2))
    res = study.run_spec(more, out, resume=True, flow_cache=root / "flows")
    assert res.ran == 3 and len(res.rows) == 9


def test_cli_interrupted_keeps_the_tables_of_what_finished(tiny, tmp_path, monkeypatch, capsys):
    from jaxvo.host.services.progress import Progress

    _, path, root, first = tiny
    calls = []

    def interrupt_third(self, done, total=None):
        calls.append(done)
        if len(calls) == 3:
            raise KeyboardInterrupt

    monkeypatch.setattr(Progress, "__call__", interrupt_third)
    out = tmp_path / "cut"
    assert main(["study", str(path), "--out", str(out), "--flow-cache", str(root / "flows"),
                 "--no-plot"]) == 130
    assert "2 finished runs kept" in capsys.readouterr().err
    rows = json.loads((out / "results.json").read_text())
    assert [r["digest"] for r in rows] == [r["digest"] for r in first.rows[:2]]


def test_cli_ctrl_c_stops_after_the_current_call_and_exits_130(tiny, tmp_path, monkeypatch,
                                                              capsys):
    """A real SIGINT during the study's first call: it printed "stopping after the current
    step", then ran every other run and exited 0. It stops after that call, keeps its run,
    says so and exits 130; and the exit's own clean-up is made quiet."""
    import signal

    import jaxvo.cli.main
    from jaxvo.host.services.progress import Progress

    _, path, root, first = tiny
    quieted = []
    monkeypatch.setattr(jaxvo.cli.main, "quiet_interrupts_at_exit", lambda: quieted.append(1))

    def ctrl_c_in_the_first_call(self, done, total=None):
        if done == 0:  # before the first call: the SIGINT arrives while it runs
            os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(Progress, "__call__", ctrl_c_in_the_first_call)
    out = tmp_path / "cut"
    assert main(["study", str(path), "--out", str(out), "--flow-cache", str(root / "flows"),
                 "--no-plot"]) == 130
    err = capsys.readouterr().err
    assert "stopping after the current step" in err
    assert "interrupted: 1 finished runs kept" in err and "--resume" in err
    kept = study.read_runs(out / study.RUNS_FILE)
    assert [r["digest"] for r in kept.values()] == [first.rows[0]["digest"]]
    assert quieted == [1]


def test_a_ctrl_c_in_jax_s_clean_up_at_exit_prints_no_traceback():
    """JAX releases its backends at the interpreter's exit; a Ctrl-C landing there printed
    a KeyboardInterrupt traceback after a finished study. A stand-in for that clean-up,
    registered before the command's call as JAX's is, receives the Ctrl-C."""
    code = ("import atexit, os, signal, time\n"
            "import jax\n"
            "from jaxvo.cli.main import quiet_interrupts_at_exit\n"
            "atexit.register(lambda: (os.kill(os.getpid(), signal.SIGINT), time.sleep(5)))\n"
            "quiet_interrupts_at_exit()\n")
    done = python_code(code)
    assert done.returncode == 130 and "Traceback" not in done.stderr, done.stderr[-2000:]


def test_a_study_of_100000_configurations_says_so_within_seconds(tmp_path):
    """Its first line came after more than 150 s: the Config of each run was built anew
    for every run (its id, the memory check, the grouping), 0.4 ms each."""
    import time

    values = [round(0.05 * (i + 1), 2) for i in range(10)]
    grid = {k: values for k in ("lam", "delta", "confidence", "pixel_sigma", "depth_coeff")}
    spec = study.parse_spec({"sequences": [{"scene": "static", "frames": 3}], "grid": grid,
                             "fixed": {"cell": 32}})

    class FirstLine(Exception):
        pass

    def log(line):
        raise FirstLine(line)

    t0 = time.perf_counter()
    with pytest.raises(FirstLine, match="100000 of 100000 runs to do"):
        study.run_spec(spec, tmp_path / "out", log=log)
    assert time.perf_counter() - t0 < 30  # seconds on a loaded 2-core machine (was > 150)


def test_cli_writes_the_tables_and_a_plot(tiny, tmp_path, capsys):
    _, path, root, first = tiny
    out = tmp_path / "cli"
    assert main(["study", str(path), "--out", str(out), "--flow-cache", str(root / "flows"),
                 "-q"]) == 0
    text = capsys.readouterr().out
    assert "6 of 6 runs" in text and "| handheld_fast_s0 |" in text
    with (out / "results.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 6 and set(Params._fields) <= set(rows[0])
    assert rows[0]["rpe_trans_m_per_s"] == ""  # 8 frames last under a second
    assert [r["digest"] for r in rows] == [r["digest"] for r in first.rows]
    assert (out / "plot.png").stat().st_size > 1000
    summary = json.loads((out / "summary.json").read_text())
    assert [e["seeds"] for e in summary] == [2, 2, 2]


# --------------------------------------------------------------------------- the tables


def test_summary_over_seeds_and_the_plotted_points(tmp_path):
    spec = study.parse_spec({"sequences": [{"scene": "static"}], "seeds": [0, 1, 2],
                             "metrics": ["ate_rmse_m", "moving_f"],
                             "grid": {"lam": [100.0, 1000.0], "max_age": [5.0, 15.0]}})
    rng = np.random.default_rng(0)
    rows = [{"sequence": "static_s0", **c, "seed": s, "ate_rmse_m": float(rng.random()),
             "moving_f": None} for c in spec.configs for s in spec.seeds]
    summary = summarise(spec, rows)
    assert len(summary) == 4
    for e, c in zip(summary, spec.configs, strict=True):
        v = [r["ate_rmse_m"] for r in rows if r["lam"] == c["lam"]
             and r["max_age"] == c["max_age"]]
        assert e["seeds"] == 3
        assert e["ate_rmse_m_mean"] == pytest.approx(np.mean(v), abs=1e-15)
        assert e["ate_rmse_m_std"] == pytest.approx(np.std(v), abs=1e-15)
        assert (e["ate_rmse_m_min"], e["ate_rmse_m_max"]) == (min(v), max(v))
        assert e["moving_f_mean"] is None
    # lam against the base max_age (15, the default, is in the grid): the max_age 5 runs
    # are left out
    x, y, s = plot_points(spec, summary, "lam", "ate_rmse_m")["static_s0"]
    at15 = [e for e in summary if e["max_age"] == 15.0]
    assert list(x) == [100.0, 1000.0]
    assert list(y) == [e["ate_rmse_m_mean"] for e in at15]
    assert list(s) == [e["ate_rmse_m_std"] for e in at15]
    assert plot_points(spec, summary, "lam", "moving_f") == {}

    status = write_report(spec, rows, tmp_path, plot=False)
    assert set(status.values()) == {"written"} and "plot.png" not in status
    md = (tmp_path / "summary.md").read_text()
    assert "| sequence | lam | max_age | seeds | ate_rmse [mm] | moving_f |" in md
    assert json.loads((tmp_path / "results.json").read_text())[0]["moving_f"] is None


def test_without_matplotlib_the_plot_is_skipped_and_said_so(tmp_path, monkeypatch):
    spec = study.parse_spec({"sequences": [{"scene": "static"}], "sweep": {"lam": [10.0]}})
    rows = [{"sequence": "static_s0", **c, "seed": 0, "ate_rmse_m": 0.01} for c in spec.configs]
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib now fails
    status = write_report(spec, rows, tmp_path)
    assert status["plot.png"].startswith("matplotlib is not installed")
    assert not (tmp_path / "plot.png").exists() and (tmp_path / "results.csv").is_file()


@pytest.mark.parametrize("metric, label, scale", [
    ("ate_rmse_m", "ate_rmse [mm]", 1000.0),
    ("rpe_trans_m_per_frame", "rpe_trans [mm/frame]", 1000.0),
    ("rpe_rot_deg_per_s", "rpe_rot [deg/s]", 1.0),
    ("moving_f", "moving_f", 1.0),
    ("seconds", "seconds [s]", 1.0),
])
def test_lengths_read_in_millimetres(metric, label, scale):
    from jaxvo.study.report import display

    assert display(metric) == (label, scale)


@pytest.mark.slow  # 11-25 s here: a whole run or study compiled afresh
def test_a_dropped_frame_scores_as_jaxvo_run_scores_it(tmp_path):
    """A black frame in the middle of a folder is dropped and the next frame pairs with the
    last good one; the study's timestamps, start pose and scores must be those of the
    frames kept, as in ``run_sequence`` (all of them shifted one frame before). Nine
    frames, one dropped, in calls of one configuration: the tiny study's 7 pairs, batch
    and Config (the noise calibration on), so the study runs the program the tiny study
    compiled."""
    import cv2

    from jaxvo.host.readers.io import open_sequence
    from jaxvo.odometry import run_sequence
    from jaxvo.synth.scenes import make_sequence, write_sequence

    folder = tmp_path / "seq"
    write_sequence(make_sequence("handheld_slow", frames=9, seed=0), folder)
    black = sorted((folder / "rgb").iterdir())[4]
    cv2.imwrite(str(black), np.zeros((480, 640, 3), np.uint8))
    spec = folder_spec(tmp_path, folder, seed=0, cell=32, num_hypotheses=4,
                       noise_calibration=True)
    res = study.run_spec(spec, tmp_path / "out", flow_cache=tmp_path / "flows")
    data, cached = study.sequence_data(spec.sequences[0], Config(cell=32), tmp_path / "flows")
    assert cached

    ref = run_sequence(open_sequence(folder),
                      cfg=Config(cell=32, num_hypotheses=4, noise_calibration=True))
    assert list(ref.dropped) == [4] and list(ref.frames) == [0, 1, 2, 3, 5, 6, 7, 8]
    np.testing.assert_array_equal(data.timestamps, ref.trajectory.timestamps)
    np.testing.assert_array_equal(data.T_w_c0, ref.trajectory.poses[0])
    assert data.flows.valid.shape[0] == len(ref.frames) - 1
    # the study vmaps the scan that run_sequence runs alone: float32 rounding apart
    expected = trajectory_scores(data.groundtruth, ref.trajectory)["ate_rmse_m"]
    assert res.rows[0]["ate_rmse_m"] == pytest.approx(expected, rel=1e-3, abs=1e-5)


@pytest.mark.slow  # the keyframe study compiled afresh (the keyframe step: test_cli_run's)
def test_a_study_with_keyframes_scores_as_jaxvo_run_keyframes(tmp_path, capsys):
    """``keyframes = true`` in a spec runs the keyframes: the study's ATE is that of
    ``jaxvo run --keyframes`` on the same frames with the same seed and settings (the study
    vmaps the scan, the command streams the step: float32 rounding apart, measured 1.7e-4
    relative). 24 frames of the fast hand-held scene at the default settings take a second
    keyframe (the window refines); frame to frame the study's ATE there is 0.50 mm, with
    keyframes 0.17 mm, so a study that ran frame to frame could not pass. The command's
    step is the one ``jaxvo run --keyframes`` compiles in test_cli_run.py."""
    from jaxvo.host.readers.io import open_sequence
    from jaxvo.synth.scenes import make_sequence, write_sequence
    from jaxvo.trajectory import read_trajectory

    folder = tmp_path / "seq"
    write_sequence(make_sequence("handheld_fast", frames=24, seed=1), folder)
    traj = tmp_path / "traj.txt"
    assert main(["run", str(folder), "--out", str(traj), "--keyframes", "--seed", "3", "-q",
                 "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["keyframes"] >= 2  # the window refined at least once
    spec = folder_spec(tmp_path, folder, seed=3, keyframes=True)
    res = study.run_spec(spec, tmp_path / "out", flow_cache=tmp_path / "flows")
    data, cached = study.sequence_data(spec.sequences[0], Config(keyframes=True),
                                       tmp_path / "flows")
    # the cache holds the keyframe flow: the same keyframes as the command took
    assert cached and data.keyframes is not None
    assert data.keyframes.valid.shape[0] == data.flows.valid.shape[0] == 23
    assert 1 + int(np.sum(data.keyframes.renew)) == summary["keyframes"]
    gt = open_sequence(folder).groundtruth
    expected = trajectory_scores(gt, read_trajectory(traj))["ate_rmse_m"]
    assert res.rows[0]["ate_rmse_m"] == pytest.approx(expected, rel=1e-3, abs=0)


# --- nothing lost (issue 46) -----------------------------------------------------------------


def test_rows_holding_only_ids_are_no_finished_runs(tiny, tmp_path):
    """--resume over a runs.jsonl whose rows held only run ids: KeyError: 'sequence'."""
    import shutil

    spec, _, root, _res = tiny
    out = tmp_path / "out"
    shutil.copytree(root / "one", out, ignore=shutil.ignore_patterns("flows"))
    lines = (out / study.RUNS_FILE).read_text().splitlines()
    ids = [json.loads(line)["id"] for line in lines]
    (out / study.RUNS_FILE).write_text("\n".join(
        [json.dumps({"id": i}) for i in ids[:2]] + lines[2:]) + "\n")
    with pytest.warns(UserWarning, match="2 line.* hold no finished run"):
        rows = study.finished_rows(spec, out)
    assert [r["id"] for r in rows] == ids[2:]
    write_report(spec, rows, out, plot=False)  # the tables of what did finish
    # resumed: the first process says the size before any flow or compile (a study of
    # 100,000 configurations printed 0/200000 for minutes), and runs the two again
    said = []
    with pytest.warns(UserWarning, match="2 line.* hold no finished run"):
        again = study.run_spec(spec, out, resume=True, flow_cache=root / "flows",
                               log=said.append)
    assert said[0].startswith("2 of 6 runs to do (1 sequences x 3 configurations x 2 seeds)")
    assert again.ran == 2 and len(again.rows) == 6


def test_processes_say_they_wait_and_stop_in_one_line(tmp_path):
    """--num-processes 2 --process-id 0 with no second process: silent for 300 s, then exit
    134 with a native stack trace from JAX."""
    port = _free_port()
    for pid, needle in ((0, r"process\(es\) 1 did not join at 127.0.0.1"),
                        (1, "process 0 did not answer within 0.5 s")):
        said = []
        with pytest.raises(InputError, match=needle):
            study.init_distributed(f"127.0.0.1:{port}", 2, pid, timeout=0.5, say=said.append)
        assert said and "waiting up to 0.5 s" in said[0]


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (Linux)")
def test_a_full_disk_names_the_runs_file():
    with pytest.raises(OSError, match="No space left on device") as got:
        study._append_runs(Path("/dev/full"), [{"id": "x"}])
    assert got.value.filename == "/dev/full"
