"""Bad input at the command line's options: refused before any work, one line naming it.

jaxvo run, synth, demo and study options out of range or that cannot go together, and
the order of the answers (options and files before JAX loads).

The answers every case expects and the sequence each breaks: tests/bad_input.py.
"""

from __future__ import annotations

import json
import os

import pytest
from bad_input import (
    assert_one_line_error,
    base,  # noqa: F401 (fixtures)
    cli,
    copy_seq,
)
from conftest import python_code


@pytest.mark.parametrize(
    "args, needles",
    [
        (["--cell", "0"], ["--cell must be at least 4 pixels, got 0"]),
        (["--cell", "3"], ["--cell must be at least 4"]),
        (["--cell", "1000"], ["--cell 1000 leaves fewer than 2 x 2 grid cells", "640x480"]),
        (["--hypotheses", "0"], ["--hypotheses must be at least 1"]),
        (["--seed", "-1"], ["--seed must be a whole number from 0 to 4294967295"]),
        (["--seed", str(2**32)], ["--seed must be", "got 4294967296"]),
        (["--max-diff", "-1"], ["--max-diff must be a number of seconds >= 0"]),
        (["--max-diff", "nan"], ["--max-diff", "nan"]),
        (["--frames", "1"], ["--frames must be at least 2"]),
        # the consecutive-frame window is gone: its option says what replaced it
        (["--window", "5"], ["--window was removed: --keyframes refines a window over"]),
    ],
)
def test_run_option_out_of_range_is_one_line_naming_it(base, tmp_path, capsys, args, needles):
    res = cli(capsys, "run", base, "--out", tmp_path / "t.txt", *args)
    assert_one_line_error(res, *needles)
    assert not (tmp_path / "t.txt").exists()  # refused before anything was written


@pytest.mark.parametrize(
    "args, needles",
    [
        (["synth", "static", "{tmp}/o", "--frames", "2", "--seed", "-1"], ["--seed must be"]),
        (["synth", "static", "{tmp}/o", "--frames", "0"], ["frames must be at least 1"]),
        (["demo", "--seed", "-1", "--peers", "none"], ["--seed must be"]),
        (["demo", "--frames", "1", "--peers", "none"], ["--frames must be at least 2"]),
        (["demo", "--peers", "nope"], ["unknown peer(s) nope"]),
    ],
)
def test_synth_and_demo_options_out_of_range(tmp_path, capsys, args, needles):
    res = cli(capsys, *(a.format(tmp=tmp_path) for a in args))
    assert_one_line_error(res, *needles)


def test_start_pose_gt_without_ground_truth(base, tmp_path, capsys):
    seq = copy_seq(base, tmp_path / "seq")
    (seq / "groundtruth.txt").unlink()
    assert_one_line_error(
        cli(capsys, "run", seq, "--out", tmp_path / "t.txt", "--start-pose", "gt"),
        "start pose gt: no ground truth of the first frame")


@pytest.mark.parametrize("value", ["525,525,319.5", "525,525,a,239.5", "525,525,319.5,239.5,1"])
def test_intrinsics_option_takes_four_numbers(base, tmp_path, capsys, value):
    assert_one_line_error(cli(capsys, "run", base, "--out", tmp_path / "t.txt", "--intrinsics",
                              value), "--intrinsics must be four numbers fx,fy,cx,cy")


@pytest.mark.parametrize("count", ["0", "1000"])
def test_study_cpu_devices_beyond_the_cores_is_one_line(tmp_path, capsys, count):
    """1000 CPU devices compiled a 3-frame study past 5 minutes at 8.8 GB."""
    spec = tmp_path / "s.json"
    spec.write_text(json.dumps({"sequences": [{"path": str(tmp_path / "missing")}]}))
    cores = len(os.sched_getaffinity(0))
    res = cli(capsys, "study", spec, "--out", tmp_path / "r", "--cpu-devices", count)
    assert_one_line_error(res, f"--cpu-devices must be 1 to {cores} (this machine's cores",
                          f"got {count}")


def test_one_line_answers_about_options_and_files_come_before_jax_loads(base, tmp_path):
    """`jaxvo run /missing` took 0.75-0.95 s: JAX (0.37 s of imports) loaded first, for the
    compile cache. Each command's checks now run before (bench: median 0.20 s against
    0.89 s before, 7 runs each on a loaded 2-core machine)."""
    full = tmp_path / "full"
    full.mkdir()
    (full / "x").write_text("")
    cases = [
        ["run", str(tmp_path / "missing"), "--out", str(tmp_path / "t.txt")],
        ["run", str(base), "--out", str(tmp_path / "t.txt"), "--depth-scale", "1e-300"],
        ["run", str(base), "--out", str(base / "rgb.txt")],
        ["study", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "s")],
        ["synth", "static", str(full), "--frames", "3"],
        ["demo", "--frames", "1"],
    ]
    code = ("import json, sys\nfrom jaxvo.cli.main import main\n"
            f"codes = [main(argv) for argv in {cases!r}]\n"
            "print(json.dumps([codes, sorted(m for m in ('jax', 'jaxlib') if m in sys.modules)]))\n")
    done = python_code(code)
    codes, loaded = json.loads(done.stdout.splitlines()[-1])
    assert codes == [2] * len(cases) and loaded == [], (codes, loaded, done.stderr)
    lines = done.stderr.splitlines()
    assert len(lines) == len(cases) and all(ln.startswith("jaxvo: error: ") for ln in lines)
