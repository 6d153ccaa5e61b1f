"""Bad input at jaxvo eval: its trajectories, options, plot format and outputs.

Astronomical coordinates, options out of range, an image format matplotlib cannot
write, and outputs over the trajectories read: one line before any work.

The answers every case expects and the sequence each breaks: tests/bad_input.py.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from bad_input import (
    assert_one_line_error,
    base,  # noqa: F401 (fixtures)
    cli,
)

from jaxvo.cli.main import main


def test_eval_on_astronomical_coordinates(tmp_path, capsys):
    rng = np.random.default_rng(0)
    for name, size in (("gt.txt", 1.0), ("est.txt", 1e200), ("ok.txt", 1e90)):
        rows = [f"{i / 10:.6f} " + " ".join(f"{size * v:.6e}" for v in rng.normal(size=3))
                + " 0 0 0 1" for i in range(10)]
        (tmp_path / name).write_text("\n".join(rows) + "\n")
    assert_one_line_error(cli(capsys, "eval", "ate", tmp_path / "gt.txt", tmp_path / "est.txt"),
                          "est.txt: a position lies", "e+200 m from the origin")
    # large but representable: scored, finite
    res = cli(capsys, "eval", "ate", tmp_path / "gt.txt", tmp_path / "ok.txt", "--json")
    assert res.rc == 0 and np.isfinite(json.loads(res.out)["results"]["trans"]["rmse"])


def test_eval_outputs_never_go_over_its_trajectories_or_each_other(base, tmp_path, capsys):
    gt = tmp_path / "gt.txt"
    shutil.copy(base / "groundtruth.txt", gt)
    before = gt.read_bytes()
    for option in ("--save_results", "--plot"):
        res = cli(capsys, "eval", "ate", gt, gt, option, gt)
        assert_one_line_error(res, option, "would overwrite the input")
        assert gt.read_bytes() == before
    res = cli(capsys, "eval", "ate", gt, gt, "--save_results", tmp_path / "r", "--plot",
              tmp_path / "r")
    assert_one_line_error(res, "--plot and --save_results are the same file")
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("args, needles", [
    (["rpe", "--delta", "inf"], ["--delta must be a positive number of frames, got inf"]),
    (["rpe", "--delta", "nan"], ["--delta must be a positive number of frames, got nan"]),
    (["rpe", "--delta", "inf", "--delta_unit", "s"], ["positive number of seconds, got inf"]),
    (["rpe", "--delta", "0", "-u", "seconds"], ["positive number of seconds, got 0"]),
    (["ate", "--max-diff", "nan"], ["--max-diff must be a number of seconds >= 0, got nan"]),
    (["ate", "--t_max_diff", "inf"], ["--max-diff", "got inf"]),
    (["rpe", "--delta_unit", "m"], ["--delta_unit 'm'", "not offered"]),
])
def test_eval_options_out_of_range_are_one_line_before_any_work(base, tmp_path, capsys, args,
                                                                 needles):
    """--delta inf raised OverflowError, --delta nan ValueError; both now say the option,
    and before the files are read (a missing estimate is not what is named)."""
    gt = base / "groundtruth.txt"
    res = cli(capsys, "eval", args[0], gt, tmp_path / "missing.txt", *args[1:])
    assert_one_line_error(res, *needles)


@pytest.mark.parametrize("plot, needle", [
    ("out.xyz", "its extension .xyz names no image format matplotlib writes"),
    ("out", "no extension names no image format"),
    ("out.png.docx", ".docx names no image format"),
])
def test_eval_plot_format_is_checked_before_any_work(base, tmp_path, capsys, plot, needle):
    pytest.importorskip("matplotlib", reason="--plot needs matplotlib (jaxvo[plot])")
    gt = base / "groundtruth.txt"
    res = cli(capsys, "eval", "ate", gt, tmp_path / "missing.txt", "--plot", tmp_path / plot)
    assert_one_line_error(res, needle, ".png", ".pdf", ".svg")
    assert list(tmp_path.iterdir()) == []
    res = cli(capsys, "eval", "ate", gt, gt, "--plot", tmp_path / "ok.JPG", "--json")
    assert res.rc == 0 and (tmp_path / "ok.JPG").read_bytes()[:2] == b"\xff\xd8", res.err


def test_eval_ate_help_says_what_scale_does_with_and_without_the_alignment(capsys):
    with pytest.raises(SystemExit):
        main(["eval", "ate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "with the alignment Sim(3), as evo's -as; with --no-align the scale alone" in text
