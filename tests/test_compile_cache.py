"""The persistent compile cache: where it goes (option > environment > JAX's > default),
that it is said when a program compiles and not when it comes from the cache, and that
several processes can share it. Each compile is checked in a child process: JAX opens its
cache once per process, and the tests' own process keeps it off (conftest)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest
from conftest import python_code

from jaxvo import __version__
from jaxvo.cli.main import build_parser, main
from jaxvo.errors import InputError
from jaxvo.host.services.compile_cache import ENV, choose_compile_cache, setup_compile_cache
from jaxvo.trajectory import read_trajectory

VERSIONED = f"jaxvo-{__version__}_jax-{jax.__version__}"

# A child that compiles a program of N unrolled operations (250: about 2 s to compile, 0.05 s
# to load from the cache here) with the cache given as its first argument, saying so when it
# compiles for 0.5 s; it prints its compile notes as JSON.
CHILD = """
import json, sys
import jax, jax.numpy as jnp
from jaxvo.host.services.compile_cache import announce_compile, setup_compile_cache
setup_compile_cache(sys.argv[1])

@jax.jit
def program(x):
    for k in range(int(sys.argv[2])):
        x = jnp.sin(x @ x + k)
    return x

with announce_compile("a test program", stream=sys.stderr, after=0.5) as notes:
    program(jax.numpy.ones((4, 4))).block_until_ready()
print(json.dumps([n._asdict() for n in notes]))
"""


def start_child(cache: str, ops: int = 250) -> subprocess.Popen:
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    return subprocess.Popen([sys.executable, "-c", CHILD, cache, str(ops)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)


def finish(proc: subprocess.Popen) -> tuple[list[dict], str]:
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err[-2000:]
    return json.loads(out.splitlines()[-1]), err


def run_child(cache: str, ops: int = 250) -> tuple[list[dict], str]:
    return finish(start_child(cache, ops))


def entries(folder: Path) -> list[Path]:
    """The cache entries of the child's program (JAX names them after the function)."""
    return sorted(folder.glob("jit_program-*-cache"))


# --- where the cache goes -------------------------------------------------------------------


def test_the_option_wins_over_the_environment_which_wins_over_the_defaults(tmp_path):
    env = {ENV: str(tmp_path / "env"), "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "jax"),
           "XDG_CACHE_HOME": str(tmp_path / "xdg"), "HOME": str(tmp_path / "home")}
    assert choose_compile_cache(tmp_path / "opt", environ=env) == (
        tmp_path / "opt" / VERSIONED, "--compile-cache")
    assert choose_compile_cache("off", environ=env) == (None, "--no-compile-cache")
    assert choose_compile_cache(None, environ=env) == (tmp_path / "env" / VERSIONED, ENV)
    assert choose_compile_cache(None, environ={**env, ENV: "OFF"}).folder is None
    del env[ENV]
    # JAX's own setting is the user's cache: used as it is, no subfolder
    assert choose_compile_cache(None, environ=env) == (tmp_path / "jax",
                                                       "JAX_COMPILATION_CACHE_DIR")
    del env["JAX_COMPILATION_CACHE_DIR"]
    assert choose_compile_cache(None, environ=env) == (
        tmp_path / "xdg" / "jaxvo" / "xla" / VERSIONED, "default")
    del env["XDG_CACHE_HOME"]
    assert choose_compile_cache(None, environ=env).folder == (
        tmp_path / "home" / ".cache" / "jaxvo" / "xla" / VERSIONED)
    assert choose_compile_cache(None, environ={**env, ENV: ""}).source == "default"


def test_the_options_are_on_the_commands_that_compile(capsys):
    parser = build_parser()
    assert parser.parse_args(["run", "s", "--out", "t", "--no-compile-cache"]).compile_cache == "off"
    assert parser.parse_args(["study", "spec.toml", "--out", "o", "--compile-cache", "d"]
                             ).compile_cache == "d"
    assert parser.parse_args(["synth", "handheld_slow", "o"]).compile_cache is None
    with pytest.raises(SystemExit) as err:  # one or the other
        parser.parse_args(["run", "s", "--out", "t", "--compile-cache", "d", "--no-compile-cache"])
    assert err.value.code == 2
    with pytest.raises(SystemExit):  # eval compiles nothing
        parser.parse_args(["eval", "ate", "a.txt", "b.txt", "--no-compile-cache"])
    capsys.readouterr()


def test_a_folder_that_cannot_be_written_is_an_error_if_given_else_a_warning(tmp_path, capsys):
    a_file = tmp_path / "file"
    a_file.write_text("")
    for option, environ in ((str(a_file), {}), (None, {ENV: str(a_file)})):
        with pytest.raises(InputError, match=r"compile cache .* cannot write there"):
            setup_compile_cache(option, environ=environ)
    rc = main(["run", str(tmp_path), "--out", str(tmp_path / "t.txt"), "--compile-cache",
               str(a_file)])
    assert rc == 2 and capsys.readouterr().err.count("\n") == 1  # one line
    # the default folder (a read-only home): the run goes on without the cache, said once
    choice = setup_compile_cache(None, environ={"XDG_CACHE_HOME": str(a_file)})
    assert choice.folder is None
    assert "running without it" in capsys.readouterr().err


# --- compiling, loading, sharing ------------------------------------------------------------


def test_a_compile_is_said_with_its_time_and_a_load_says_it_loads(tmp_path):
    notes, err = run_child(str(tmp_path))
    assert [n["from_cache"] for n in notes] == [False]
    assert ("jaxvo: preparing a test program (compiled once per machine and cached) ... "
            "compiled (first run with these settings on this machine) in ") in err
    assert err.rstrip().endswith(" s")
    assert len(entries(tmp_path / VERSIONED)) == 1

    notes, err = run_child(str(tmp_path))
    assert [n["from_cache"] for n in notes] == [True]
    # quick on a quiet machine (nothing said), seconds on a busy one: then said as a load
    assert "compiled (" not in err and "compiled in" not in err
    assert all("loaded from the compile cache in" in ln for ln in err.splitlines()
               if "a test program" in ln)

    notes, err = run_child("off")
    assert [n["from_cache"] for n in notes] == [False]
    assert "compiling a test program (the compile cache is off) ... " in err


def test_processes_share_the_folder_and_an_entry_cut_short_is_compiled_again(tmp_path):
    folder = tmp_path / VERSIONED
    # a quicker program (every program is stored, however quick to compile)
    both = [start_child(str(tmp_path), ops=40) for _ in range(2)]  # cold, at the same time
    for proc in both:
        _, err = finish(proc)
        assert "persistent compilation cache" not in err  # no read or write error
    [entry] = entries(folder)
    assert entry.stat().st_size > 0
    # bounded, hence locked: JAX keeps each entry's access time only then
    assert Path(str(entry)[: -len("cache")] + "atime").is_file()

    entry.write_bytes(b"")  # a process killed between creating the entry and writing it
    _, err = run_child(str(tmp_path), ops=40)
    assert "persistent compilation cache" not in err  # not read: compiled again...
    assert entry.stat().st_size > 0  # ...and stored


# The step the commands' tests compile afresh: a smaller one than the default (two
# hypotheses, 32-pixel cells), over a 3-frame synthetic sequence
STEP_OPTIONS = ("--hypotheses", "2", "--cell", "32")


@pytest.fixture(scope="module")
def command_runs(tmp_path_factory):
    """Two runs of ``jaxvo run`` with one fresh cache folder: the first compiles the step,
    the second loads it. ``(folder, sequence, [(summary, stderr, trajectory)] * 2)``; the
    Python test below loads the same step from the same folder."""
    from jaxvo.synth.scenes import make_sequence, write_sequence

    root = tmp_path_factory.mktemp("command_cache")
    seq_dir = root / "seq"
    write_sequence(make_sequence("handheld_slow", frames=3, seed=0), seq_dir)
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    runs = []
    for k in range(2):
        out = root / f"t{k}.txt"
        proc = subprocess.run(
            [sys.executable, "-m", "jaxvo.cli.main", "run", str(seq_dir), "--out", str(out),
             "--json", "--compile-cache", str(root / "cache"), *STEP_OPTIONS],
            capture_output=True, text=True, env=env, timeout=600, check=False)
        assert proc.returncode == 0, proc.stderr[-2000:]
        runs.append((json.loads(proc.stdout), proc.stderr, read_trajectory(out)))
    return root / "cache", seq_dir, runs


@pytest.mark.slow  # a whole run compiled afresh
def test_jaxvo_run_compiles_once_then_loads_the_step_with_the_same_poses(command_runs):
    """Two runs of ``jaxvo run`` on a 3-frame synthetic sequence with a fresh cache folder:
    the first compiles the step and says so, the second loads it from the cache (and, where
    the load is slow enough to be announced, says that it loads) and estimates the same
    poses. The test reads the mechanism (``from_cache``), never a clock: under load a
    cache load takes seconds."""
    _, _, [(cold, cold_err, cold_traj), (warm, warm_err, warm_traj)] = command_runs
    assert "jaxvo: preparing the per-frame step (compiled once per machine and cached) ... " \
        "compiled (first run with these settings on this machine) in" in cold_err
    assert [c["from_cache"] for c in cold["compile"]] == [False]
    assert [c["from_cache"] for c in warm["compile"]] == [True]
    assert "compiled" not in warm_err.replace("compiled once per machine", "")
    said = [ln for ln in warm_err.splitlines() if "the per-frame step" in ln]
    assert all(ln.endswith(" s") and "loaded from the compile cache in" in ln for ln in said)
    np.testing.assert_array_equal(warm_traj.poses, cold_traj.poses)  # bit for bit


def test_the_command_line_starts_without_jax_or_opencv():
    """``jaxvo --help``, ``--version`` and one-line errors wait for no heavy import: the
    package's names load lazily (they took 1.0-1.5 s, 4 s on a busy machine, when
    ``import jaxvo`` imported every module)."""
    code = ("import sys, jaxvo, jaxvo.cli.main\n"
            "jaxvo.cli.main.build_parser()\n"
            "heavy = sorted(m for m in ('jax', 'cv2') if m in sys.modules)\n"
            "assert not heavy, heavy\n"
            "assert jaxvo.Odometry.__name__ == 'Odometry' and 'jax' in sys.modules\n"
            "assert set(jaxvo.__all__) <= set(dir(jaxvo))\n")
    done = python_code(code)
    assert done.returncode == 0, done.stderr[-2000:]


# --- a busy or broken cache never fails a command ----------------------------------------

# A child that turns the cache on in argv[1] with the lock wait cut to 0.5 s, makes every
# entry write fail as a full disk does when argv[2] is "full", and compiles three programs.
BROKEN_CHILD = """
import errno, sys
import jax, jax.numpy as jnp
from jax._src import lru_cache
from jaxvo.host.services import compile_cache
compile_cache.LOCK_TIMEOUT_S = 0.5
if sys.argv[2] == "full":
    def put(self, key, value):
        raise OSError(errno.ENOSPC, "No space left on device")
    lru_cache.LRUCache.put = put
choice = compile_cache.setup_compile_cache(sys.argv[1])
for k in range(3):
    jax.jit(lambda x, k=k: jnp.sin(x) * k + x)(jnp.ones(4)).block_until_ready()
print("on" if choice.folder else "off")
"""


def run_broken_child(cache: Path, how: str) -> tuple[str, list[str]]:
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    done = subprocess.run([sys.executable, "-c", BROKEN_CHILD, str(cache), how],
                          capture_output=True, text=True, timeout=300, env=env, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout.strip(), [ln for ln in done.stderr.splitlines() if ln.strip()]


def test_a_cache_locked_by_another_process_is_one_warning_and_the_run_goes_on(tmp_path):
    """Another process held the lock under heavy load: the run failed with exit 2 (filelock's
    Timeout is an OSError)."""
    import filelock

    folder = tmp_path / VERSIONED
    folder.mkdir()
    with filelock.FileLock(folder / ".lockfile"):
        state, err = run_broken_child(tmp_path, "busy")
    assert state == "off"
    assert err == [(f"jaxvo: warning: compile cache {folder} is locked by another process "
                    "for over 0.5 s; running without it")], err


def test_a_full_cache_disk_is_one_line(tmp_path):
    """Every entry JAX could not write printed a warning of its own (14 lines a run)."""
    state, err = run_broken_child(tmp_path, "full")
    assert state == "on"
    assert len(err) == 1, err
    assert err[0] == (f"jaxvo: warning: compile cache {tmp_path / VERSIONED}: writing an entry "
                      "failed (OSError: [Errno 28] No space left on device); going on without "
                      "it (further cache errors not shown)"), err


# --- the library from Python: the same cache as the commands, unless the program chose ---

# A child that uses the library as docs/python.md shows it, without setup_compile_cache:
# a program compiled first (JAX decides at its first compile whether the process uses a
# cache), then Odometry built ("construct", "off": after setup_compile_cache("off")) or run
# over the sequence folder given ("run"); prints the cache hits, JAX's cache folder and the
# poses.
PYTHON_CHILD = """
import json, sys
import jax, numpy as np
hits, traced = [], []
jax.monitoring.register_event_listener(lambda event, **kw: hits.append(event)
                                       if event == "/jax/compilation_cache/cache_hits" else None)
jax.monitoring.register_event_duration_secs_listener(
    lambda event, s, **kw: traced.append(kw.get("fun_name"))
    if event == "/jax/core/compile/jaxpr_trace_duration" else None)
jax.jit(lambda x: x + 1)(1.0).block_until_ready()
import jaxvo
if sys.argv[1] == "off":
    from jaxvo.host.services.compile_cache import setup_compile_cache
    setup_compile_cache("off")
if sys.argv[1] == "run":  # the commands' sequence and step settings (STEP_OPTIONS)
    seq = jaxvo.open_sequence(sys.argv[2])
    odo = jaxvo.Odometry(seq.intrinsics, cfg=jaxvo.Config(num_hypotheses=2, cell=32))
    for f in seq:
        odo.process(f.bgr, f.depth, f.timestamp)
else:  # the choice of cache is made when Odometry is built
    odo = jaxvo.Odometry((150.0, 150.0, 80.0, 60.0))
print(json.dumps({"hits": len(hits), "traced": traced,
                  "folder": jax.config.jax_compilation_cache_dir,
                  "poses": np.asarray(odo.trajectory.poses).tolist()}))
"""


def python_child(how: str, *args: str, **env: str | None) -> dict:
    """PYTHON_CHILD ``how ARGS`` with ``env`` set on this environment (None: unset); its
    JSON line."""
    environ = dict(os.environ)
    for name, value in env.items():
        environ.pop(name, None)
        if value is not None:
            environ[name] = value
    done = subprocess.run([sys.executable, "-c", PYTHON_CHILD, how, *args], capture_output=True,
                          text=True, timeout=600, env=environ, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.slow  # the step compiled afresh by the command (command_runs)
def test_odometry_from_python_uses_the_cache_of_the_commands(command_runs):
    """A program that uses the library without calling setup_compile_cache, and compiles
    a program of its own first, loads the step ``jaxvo run`` compiled and stored (the step
    exported: it is not traced again), with the poses the command wrote."""
    cache, seq_dir, [_, (_, _, command_traj)] = command_runs
    warm = python_child("run", str(seq_dir), JAX_PLATFORMS="cpu",  # as the command's
                        **{ENV: str(cache), "JAX_COMPILATION_CACHE_DIR": None})
    folder = cache / VERSIONED
    assert warm["folder"] == str(folder)
    assert sorted((folder / "jaxvo-exported").glob("step-*"))
    assert warm["hits"] >= 1 and "step" not in warm["traced"]  # Odometry._compiled_step
    assert len(warm["poses"]) == 3
    # the command's poses, as its file holds them (9 decimals, the rotation as a quaternion),
    # from its first pose (the command starts at the ground truth's, Odometry at the identity)
    relative = np.linalg.inv(command_traj.poses[0]) @ command_traj.poses
    np.testing.assert_allclose(np.asarray(warm["poses"]), relative, atol=1e-7)


def test_a_program_that_chose_its_cache_keeps_it(tmp_path):
    """JAX's own folder, JAXVO_COMPILE_CACHE=off or setup_compile_cache("off") before: the
    library leaves the choice as it is (and writes no folder of its own)."""
    xdg = {"XDG_CACHE_HOME": str(tmp_path / "xdg"), ENV: None}
    jax_dir = str(tmp_path / "jax")
    assert python_child("construct", **xdg, JAX_COMPILATION_CACHE_DIR=jax_dir)["folder"] == (
        jax_dir)
    assert python_child("construct", **{**xdg, ENV: "off"},
                        JAX_COMPILATION_CACHE_DIR=None)["folder"] is None
    assert python_child("off", **xdg, JAX_COMPILATION_CACHE_DIR=None)["folder"] is None
    assert not (tmp_path / "xdg").exists()
    default = python_child("construct", **xdg, JAX_COMPILATION_CACHE_DIR=None)
    assert default["folder"] == str(tmp_path / "xdg" / "jaxvo" / "xla" / VERSIONED)


@pytest.mark.parametrize("data", [b"", b"[]\n", b'["jaxvo.core.pipeline.StepOutput"]\n\x00\x01',
                                  b'["no.such.Module"]\nxx', b"\xff\xfe not json\nxx"])
def test_a_broken_exported_program_is_read_as_none_and_exported_again(tmp_path, data):
    """A cut, empty or foreign file where an exported step was kept: read as absent (the
    step is exported again), never an error of the run."""
    from jaxvo.host.services.compile_cache import _read_exported

    path = tmp_path / "step-broken"
    path.write_bytes(data)
    assert _read_exported(path) is None
    assert _read_exported(tmp_path / "absent") is None


def test_the_first_frame_compiles_one_program_not_an_operation_at_a_time():
    """``Odometry``'s first ``process`` call (the grid, the start state) compiles one
    program in a fresh process, ``jit_init``; ``Odometry(...)`` compiles none for the
    parameters, which go to the device from NumPy (the PRNG key's own programs, JAX's, are
    compiled before it is counted, so that the count does not depend on JAX's version).
    Built eagerly, the start state compiled a program per operation (dozens, 0.2 s of the
    first pose; docs/speed.md)."""
    code = ("import os; os.environ['JAXVO_COMPILE_CACHE'] = 'off'\n"
            "import jax, numpy as np\n"
            "from jaxvo.odometry import Odometry\n"
            "n = [0]\n"
            "def note(event, seconds, **kw):\n"
            "    n[0] += event == '/jax/core/compile/backend_compile_duration'\n"
            "jax.random.key(0)\n"
            "jax.monitoring.register_event_duration_secs_listener(note)\n"
            "odo = Odometry((500.0, 500.0, 160.0, 120.0))\n"
            "print(n[0])\n"
            "depth = np.full((240, 320), 5000, np.uint16)\n"
            "odo.process(np.zeros((240, 320, 3), np.uint8), depth, 0.0)\n"
            "print(n[0])\n")
    done = python_code(code)
    assert done.returncode == 0, done.stderr[-2000:]
    built, first_frame = map(int, done.stdout.split()[-2:])
    assert (built, first_frame - built) == (0, 1)
