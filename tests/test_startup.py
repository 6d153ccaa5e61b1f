"""What the command line loads before it answers: a one-line answer (a missing input, a bad
option, ``--help``) imports neither JAX nor OpenCV nor NumPy, checked in a fresh interpreter
by the modules it holds when the answer is out (the time this saves is bench/'s to measure,
not a test's)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

HEAVY = ("numpy", "jax", "cv2")

# main() in a fresh interpreter; prints the exit status and the heavy modules it loaded
CHILD = """
import json, sys
from jaxvo.cli.main import main
status = main(sys.argv[1:])
sys.stdout.flush()
print(json.dumps([status, sorted(m for m in {heavy!r} if m in sys.modules)]), file=sys.stderr)
"""


def answer(*argv: str) -> tuple[int, list[str], str, str]:
    """``jaxvo ARGV`` in a child: its status, the heavy modules it loaded, its stdout and
    stderr (the last line, the child's report, taken off)."""
    done = subprocess.run([sys.executable, "-c", CHILD.format(heavy=HEAVY), *argv],
                          capture_output=True, text=True, timeout=120, check=False)
    *err, report = done.stderr.rstrip("\n").split("\n")
    try:
        status, heavy = json.loads(report)
    except ValueError:  # argparse's exits (usage errors, --help) end main() with SystemExit
        status, heavy, err = done.returncode, None, [*err, report]
    return status, heavy, done.stdout, "\n".join(err)


def loaded_by(*argv: str) -> list[str]:
    """The heavy modules ``jaxvo ARGV`` had loaded when it exited through SystemExit or
    returned (argparse's own answers exit inside main())."""
    code = ("import sys\nfrom jaxvo.cli.main import main\n"
            "try:\n    main(sys.argv[1:])\nexcept SystemExit:\n    pass\n"
            f"import json; print(json.dumps(sorted(m for m in {HEAVY!r} if m in sys.modules)))")
    done = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True,
                          timeout=120, check=False)
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_a_missing_sequence_is_answered_before_numpy_loads(tmp_path):
    status, heavy, _, err = answer("run", str(tmp_path / "missing"), "--out",
                                   str(tmp_path / "t.txt"))
    assert status == 2
    assert err.strip() == f"jaxvo: error: sequence folder not found: {tmp_path / 'missing'}"
    assert heavy == []
    assert not (tmp_path / "t.txt").exists()


def test_the_early_answer_says_what_open_sequence_says(tmp_path):
    """One wording for a missing folder, whichever of the two finds it."""
    from jaxvo.errors import InputError
    from jaxvo.host.readers.io import open_sequence

    with pytest.raises(InputError) as exc:
        open_sequence(tmp_path / "missing")
    _, _, _, err = answer("run", str(tmp_path / "missing"), "--out", str(tmp_path / "t.txt"))
    assert err.strip() == f"jaxvo: error: {exc.value}"


@pytest.mark.parametrize("argv", [("--help",), ("--version",), ("run",), ("nonsense",),
                                  ("run", "x", "--out", "y", "--hypotheses", "many"),
                                  ("map", "x", "--traj", "y"),
                                  ("map", "x", "--traj", "y", "--out", "z", "--grow", "many")])
def test_argparse_answers_load_nothing_heavy(argv):
    assert loaded_by(*argv) == []


def test_run_help_lists_what_its_modules_hold():
    """The presets, storages and frame names in ``jaxvo run --help`` come from their
    modules when the help is printed."""
    from jaxvo.host.frontend.camera import PRESETS
    from jaxvo.host.writers.bagout import CAMERA_FRAME, STORAGES, WORLD_FRAME

    done = subprocess.run([sys.executable, "-m", "jaxvo.cli.main", "run", "--help"],
                          capture_output=True, text=True, timeout=120, check=True)
    text = " ".join(done.stdout.split())
    assert "intrinsics preset (" + ", ".join(sorted(PRESETS)) + ")" in text
    assert "the bag's storage: " + ", ".join(STORAGES) + " (default" in text
    assert f"(default {WORLD_FRAME}," in text and f"(default {CAMERA_FRAME}:" in text


def test_a_bag_storage_is_still_checked_against_the_writers():
    status, _, _, err = answer("run", "x", "--out", "y", "--bag-storage", "zip")
    assert status == 2
    assert "invalid choice: 'zip' (choose from 'mcap', 'sqlite3')" in err


def test_the_parser_of_one_command_parses_as_the_whole_one():
    from jaxvo.cli.main import build_parser

    argv = ["run", "s", "--out", "t", "--camera", "tum_fr3", "--bag-storage", "sqlite3",
            "--no-compile-cache"]
    assert vars(build_parser(("run",)).parse_args(argv)) == vars(build_parser().parse_args(argv))


def test_evals_choices_are_still_checked_against_evo_results():
    from jaxvo.evaluation.evo_results import PLOT_MODES, RELATIONS

    _, _, _, err = answer("eval", "rpe", "a", "b", "-r", "x")
    assert f"(choose from {', '.join(map(repr, sorted(RELATIONS)))})" in err
    _, _, _, err = answer("eval", "rpe", "a", "b", "--plot_mode", "q")
    assert f"(choose from {', '.join(map(repr, PLOT_MODES))})" in err


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, str]:
    """What the answers below name that is there: a trajectory, a study spec (not a valid
    one: the options are checked before it is read) and a two-frame TUM sequence whose
    poses are the trajectory's, so that each case breaks one thing."""
    import cv2
    import numpy as np

    root = tmp_path_factory.mktemp("inputs")
    seq = root / "seq"
    for kind, image in (("rgb", np.zeros((8, 8, 3), np.uint8)),
                        ("depth", np.full((8, 8), 5000, np.uint16))):
        (seq / kind).mkdir(parents=True)
        for i in range(2):
            cv2.imwrite(str(seq / kind / f"{i}.png"), image)
        (seq / f"{kind}.txt").write_text("".join(f"{i} {kind}/{i}.png\n" for i in range(2)))
    (seq / "camera.txt").write_text("fx 5\nfy 5\ncx 4\ncy 4\n")
    (root / "gt.txt").write_text("".join(f"{i} 0 0 0 0 0 0 1\n" for i in range(2)))
    (root / "spec.json").write_text("{}")
    (root / "bad.json").write_text("{")
    return {"tmp": str(root), "seq": str(seq), "gt": str(root / "gt.txt")}


def _cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()


def _scenarios() -> str:
    from jaxvo.synth.scenes import SCENARIOS

    return ", ".join(SCENARIOS)


# case -> (argv, split on spaces; the one line after "jaxvo: error: "), with {tmp}, {seq},
# {gt}, {cores} and {scenarios} filled in; each case has one thing wrong, so that the
# answer is the one the command always gave
SEED = "--seed must be a whole number from 0 to 4294967295 (2**32 - 1), got -1"
EARLY_ANSWERS = {
    "eval-gt-missing": ("eval ate {tmp}/missing.txt {gt}", "file not found: {tmp}/missing.txt"),
    "eval-est-missing": ("eval rpe {gt} {tmp}/missing.txt", "file not found: {tmp}/missing.txt"),
    "eval-gt-folder": ("eval ate {tmp} {gt}", "not a file: {tmp}"),
    "eval-max-diff": ("eval ate {gt} {gt} --max-diff -1",
                      "--max-diff must be a number of seconds >= 0, got -1.0"),
    "eval-delta": ("eval rpe {gt} {gt} --delta 0",
                   "--delta must be a positive number of frames, got 0"),
    "eval-delta-whole": ("eval rpe {gt} {gt} --delta 1.5",
                         "--delta in frames must be a whole number, got 1.5"),
    "eval-delta-unit": ("eval rpe {gt} {gt} --delta-unit d", (
        "--delta_unit 'd': jaxvo pairs poses by frames (f) or seconds; evo's d, r and m "
        "(degrees, radians, metres travelled) are not offered")),
    "eval-two-stdin": ("eval ate - -",
                       "only one of the trajectories can come from standard input (-)"),
    "eval-est-missing-with-outputs": (
        "eval ate {gt} {tmp}/missing.txt --save_results {tmp}/r.zip --plot {tmp}/p.png",
        "file not found: {tmp}/missing.txt"),
    "study-spec-missing": ("study {tmp}/missing.json --out {tmp}/s", (
        "cannot read the study spec {tmp}/missing.json: No such file or directory")),
    "study-spec-not-json": ("study {tmp}/bad.json --out {tmp}/s", (
        "{tmp}/bad.json: not valid JSON: Expecting property name enclosed in double quotes: "
        "line 1 column 2 (char 1)")),
    "study-batch": ("study {tmp}/spec.json --out {tmp}/s --batch 0",
                    "--batch must be at least 1, got 0"),
    "study-join-timeout": ("study {tmp}/spec.json --out {tmp}/s --join-timeout 0",
                           "--join-timeout must be a positive number of seconds, got 0.0"),
    "study-cpu-devices": ("study {tmp}/spec.json --out {tmp}/s --cpu-devices 0", (
        "--cpu-devices must be 1 to {cores} (this machine's cores: more devices only add "
        "compiles), got 0")),
    "synth-scenario": ("synth nonesuch {tmp}/o",
                       "unknown scenario 'nonesuch'; choose one of {scenarios}"),
    "synth-seed": ("synth static {tmp}/o --seed -1", SEED),
    "synth-frames": ("synth static {tmp}/o --frames 0", "--frames must be at least 1, got 0"),
    "synth-composite-missing": ("synth static {tmp}/o --composite {tmp}/missing",
                                "sequence folder not found: {tmp}/missing"),
    "demo-scenario": ("demo --scenario nonesuch",
                      "unknown scenario 'nonesuch'; choose one of {scenarios}"),
    "demo-frames": ("demo --frames 1", "--frames must be at least 2, got 1"),
    "demo-seed": ("demo --seed -1", SEED),
    "map-sequence-missing": ("map {tmp}/missing --traj {gt} --out {tmp}/m.ply",
                             "sequence folder not found: {tmp}/missing"),
    "map-traj-missing": ("map {seq} --traj {tmp}/missing.txt --out {tmp}/m.ply",
                         "file not found: {tmp}/missing.txt"),
    "map-masks-missing": ("map {seq} --traj {gt} --out {tmp}/m.ply --dynamic-masks {tmp}/none",
                          "--dynamic-masks {tmp}/none: not a folder"),
    "data-unknown-name": ("data get tum nonesuch --dir {tmp}/d",
                          "no tum sequence 'nonesuch' (jaxvo data list tum)"),
    "data-sha256": ("data get tum fr3/walking_xyz --dir {tmp}/d --sha256 zz",
                    "--sha256 must be 64 hexadecimal digits, got 'zz'"),
}


@pytest.mark.parametrize("case", list(EARLY_ANSWERS))
def test_each_commands_cheap_answers_come_before_numpy_loads(inputs, case):
    """Paths that are not there, unknown names and options out of range: every command
    answers them in the words it always did, with nothing heavy loaded (and nothing
    written)."""
    argv, line = EARLY_ANSWERS[case]
    if "--plot" in argv:  # without matplotlib --plot says that first
        pytest.importorskip("matplotlib")
    fill = {**inputs, "cores": _cores(), "scenarios": _scenarios()}
    status, heavy, _, err = answer(*(a.format(**fill) for a in argv.split()))
    assert (status, err.strip()) == (2, "jaxvo: error: " + line.format(**fill))
    assert heavy == []
    assert not any((Path(inputs["tmp"]) / name).exists() for name in ("o", "s", "d", "m.ply"))


# case -> (argv, the one line), as EARLY_ANSWERS: an output that cannot be written, each
# case with nothing else wrong ({gt} a file, {seq} a folder that is not empty)
OUTPUT_ANSWERS = {
    "eval-save-results-no-folder": ("eval ate {gt} {gt} --save_results {tmp}/none/r.zip",
                                    ("--save_results {tmp}/none/r.zip: folder {tmp}/none "
                                     "does not exist")),
    "eval-save-results-folder": ("eval rpe {gt} {gt} --save_results {tmp}",
                                 "--save_results {tmp}: is a folder, not a file"),
    "eval-save-results-input": ("eval ate {gt} {gt} --save_results {gt}",
                                "--save_results {gt} would overwrite the input {gt}"),
    "eval-save-results-stdout": ("eval ate {gt} {gt} --save_results -", (
        "--save_results -: --save_results writes a file, not standard output; name a file")),
    "eval-one-file-twice": ("eval ate {gt} {gt} --save_results {tmp}/r.zip --plot {tmp}/r.zip",
                            ("--plot and --save_results are the same file {tmp}/r.zip; "
                             "each output needs its own")),
    "eval-plot-no-folder": ("eval ate {gt} {gt} --plot {tmp}/none/p.png",
                            "--plot {tmp}/none/p.png: folder {tmp}/none does not exist"),
    "data-dir-file": ("data get tum fr3/walking_xyz --dir {gt}",
                      "--dir {gt}: exists and is not a folder"),
    "synth-out-not-empty": ("synth static {seq}", (
        "OUT_DIR {seq}: the folder is not empty; give a new or empty folder (nothing in it is "
        "changed)")),
    "synth-out-file": ("synth static {gt} --frames 3", "OUT_DIR {gt}: exists and is not a folder"),
    "demo-out-file": ("demo --out {gt}", "--out {gt}: exists and is not a folder"),
    "map-out-no-folder": ("map {seq} --traj {gt} --out {tmp}/none/m.ply",
                          "--out {tmp}/none/m.ply: folder {tmp}/none does not exist"),
    "map-out-folder": ("map {seq} --traj {gt} --out {tmp}", "--out {tmp}: is a folder, not a file"),
    "map-out-stdout": ("map {seq} --traj {gt} --out -",
                       "--out -: --out writes a file, not standard output; name a file"),
    "run-out-no-folder": ("run {seq} --cell 4 --out {tmp}/none/t.txt",
                          "--out {tmp}/none/t.txt: folder {tmp}/none does not exist"),
    "run-out-folder": ("run {seq} --cell 4 --out {tmp}", "--out {tmp}: is a folder, not a file"),
}


def _tree(root: Path) -> dict[str, tuple[int, int]]:
    """Every path under ``root``, with its size and modification time."""
    return {str(p): (p.stat().st_size, p.stat().st_mtime_ns) for p in sorted(root.rglob("*"))}


@pytest.mark.parametrize("case", list(OUTPUT_ANSWERS))
def test_each_commands_output_answers_come_before_numpy_loads(inputs, case):
    """An output that cannot be written (a folder missing, a file where a folder goes, a
    folder that is not empty, an input or another output): said in the words it always
    was, with nothing heavy loaded and nothing written."""
    if "plot" in case:  # without matplotlib --plot says that first
        pytest.importorskip("matplotlib")
    argv, line = OUTPUT_ANSWERS[case]
    before = _tree(Path(inputs["tmp"]))
    status, heavy, _, err = answer(*(a.format(**inputs) for a in argv.split()))
    assert (status, err.strip()) == (2, "jaxvo: error: " + line.format(**inputs))
    assert heavy == []
    assert _tree(Path(inputs["tmp"])) == before


def test_the_plot_formats_known_without_matplotlib_are_the_installed_ones():
    """A --plot named in one of these is passed before matplotlib (and NumPy) loads: each
    must be a format matplotlib writes."""
    pytest.importorskip("matplotlib")
    from matplotlib.backend_bases import FigureCanvasBase

    from jaxvo.cli.eval import PLOT_FORMATS

    assert set(PLOT_FORMATS) <= set(FigureCanvasBase.get_supported_filetypes())


def test_the_early_answers_say_what_read_trajectory_says(tmp_path):
    """One wording for a missing trajectory and a folder given as one, whichever of the
    light check or the reader finds it."""
    from jaxvo.cli.inputs import require_trajectory
    from jaxvo.errors import InputError
    from jaxvo.trajectory import read_trajectory

    for path in (tmp_path / "missing.txt", tmp_path):
        with pytest.raises(InputError) as early:
            require_trajectory(path)
        with pytest.raises(InputError) as reader:
            read_trajectory(path)
        assert str(early.value) == str(reader.value)


def test_an_unknown_scenario_is_said_as_the_scenes_say_it():
    from jaxvo.cli.synth import check_scenario
    from jaxvo.errors import InputError
    from jaxvo.synth.scenes import make_sequence

    with pytest.raises(InputError) as early:
        check_scenario("nonesuch")
    with pytest.raises(InputError) as reader:
        make_sequence("nonesuch")
    assert str(early.value) == str(reader.value)
