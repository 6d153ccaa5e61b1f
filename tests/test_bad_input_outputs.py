"""Bad input at the outputs: where a command writes, checked before any work.

Unwritable or wrong-kind paths, an output over an input or over another output (by
device and inode), standard output as a target, a closed pipe and a full disk.

The answers every case expects and the sequence each breaks: tests/bad_input.py.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from bad_input import (  # noqa: F401 (fixtures)
    FRAMES,
    assert_one_line_error,
    base,
    cli,
    copy_seq,
    data_lines,
    run_json,
    unwritable,
)

from jaxvo.cli.main import main
from jaxvo.errors import InputError
from jaxvo.trajectory import read_trajectory


@pytest.mark.parametrize("option", ["--masks", "--dynamic-masks", "--overlays"])
def test_unwritable_mask_folder(base, tmp_path, unwritable, capsys, option):
    res = cli(capsys, "run", base, "--out", tmp_path / "t.txt", option, unwritable / "m")
    assert_one_line_error(res, option, "cannot write there")


def test_unwritable_trajectory(base, unwritable, capsys):
    assert_one_line_error(cli(capsys, "run", base, "--out", unwritable / "t.txt"),
                          "--out", "cannot write")


def test_unwritable_synth_and_demo_folders(unwritable, capsys):
    assert_one_line_error(cli(capsys, "synth", "static", unwritable / "o", "--frames", "2"),
                          "OUT_DIR", "cannot write there")
    assert_one_line_error(cli(capsys, "demo", "--peers", "none", "--out", unwritable / "o"),
                          "--out", "cannot write there")


def test_output_paths_that_are_the_wrong_kind(base, tmp_path, capsys):
    assert_one_line_error(cli(capsys, "run", base, "--out", tmp_path), "--out", "is a folder")
    assert_one_line_error(cli(capsys, "run", base, "--out", tmp_path / "no" / "t.txt"),
                          "does not exist")
    (tmp_path / "file").write_text("x")
    assert_one_line_error(
        cli(capsys, "run", base, "--out", tmp_path / "t.txt", "--masks", tmp_path / "file"),
        "--masks", "exists and is not a folder")


def test_out_never_overwrites_the_sequences_own_files(base, tmp_path, capsys):
    seq = copy_seq(base, tmp_path / "seq")
    before = (seq / "groundtruth.txt").read_text()
    res = cli(capsys, "run", seq, "--out", seq / "groundtruth.txt")
    assert_one_line_error(res, "would overwrite the input")
    assert (seq / "groundtruth.txt").read_text() == before


def test_masks_and_overlays_are_png_named_by_rgb_timestamp(base, tmp_path, capsys):
    res = run_json(capsys, base, tmp_path / "t.txt", "--masks", tmp_path / "m",
                   "--dynamic-masks", tmp_path / "d", "--overlays", tmp_path / "o")
    assert res.rc == 0
    rgb = [Path(f).stem for _, f in map(str.split, data_lines(base / "rgb.txt"))]
    pairs = sorted(p.stem for p in (tmp_path / "m").iterdir())
    assert pairs == rgb[:-1]  # one per pair, named by the image its labels lie on
    assert sorted(p.stem for p in (tmp_path / "d").iterdir()) == rgb  # the last one too
    overlays = sorted((tmp_path / "o").iterdir())
    assert [p.stem for p in overlays] == rgb[:-1] and overlays[0].suffix == ".png"
    assert cv2.imread(str(overlays[0])).shape == (240, 1280, 3)  # 4 half-size panels


def test_demo_creates_its_out_folder(tmp_path, capsys, monkeypatch):
    """The README's own example wrote the peers' trajectories before creating the folder."""
    out = tmp_path / "demo_out" / "nested"
    # 4 frames: the scan of examples/quickstart_synthetic.py in test_examples.py (3 pairs)
    res = cli(capsys, "demo", "--frames", "4", "--peers", "opencv_rgb", "--out", out, "--json")
    assert res.rc == 0
    names = sorted(p.name for p in out.iterdir())
    assert {"jaxvo.txt", "opencv_rgb.txt", "groundtruth.txt"} <= set(names)
    assert any(n.startswith("overlay_") and n.endswith(".png") for n in names)


def digest_folder(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


@pytest.mark.parametrize("option", ["--masks", "--dynamic-masks", "--overlays"])
def test_run_never_writes_images_into_a_folder_it_reads(base, tmp_path, capsys, option):
    """Masks are named by the RGB timestamp, TUM's image name: into SEQ/rgb they replaced
    5 of 6 colour images, exit 0."""
    seq = copy_seq(base, tmp_path / "seq", images=("rgb",))
    before = digest_folder(seq / "rgb")
    res = cli(capsys, "run", seq, "--out", tmp_path / "t.txt", option, seq / "rgb")
    assert_one_line_error(res, option, "which this command reads", "choose another folder")
    assert digest_folder(seq / "rgb") == before and not (tmp_path / "t.txt").exists()
    # the sequence's own folder holds its lists: refused too
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt", option, seq),
                          option, "rgb.txt")


def test_run_out_is_never_an_input_image(base, tmp_path, capsys):
    seq = copy_seq(base, tmp_path / "seq", images=("rgb",))
    first = min((seq / "rgb").iterdir())
    before = first.read_bytes()
    assert_one_line_error(cli(capsys, "run", seq, "--out", first),
                          "--out", "would overwrite the input", first.name)
    assert first.read_bytes() == before
    # through a link to the same folder: the same file
    (tmp_path / "link").symlink_to(seq / "rgb", target_is_directory=True)
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "link" / first.name),
                          "would overwrite the input")


def test_run_outputs_never_share_a_folder(base, tmp_path, capsys):
    x = tmp_path / "x"
    res = cli(capsys, "run", base, "--out", tmp_path / "t.txt", "--masks", x,
              "--dynamic-masks", x, "--overlays", x)
    assert_one_line_error(res, "--dynamic-masks and --masks are the same folder")
    assert not x.exists()  # refused before any folder was made
    res = cli(capsys, "run", base, "--out", x / "t.txt", "--masks", x)
    assert_one_line_error(res, "--out", "lies in the folder of --masks")


def test_synth_never_writes_into_a_folder_with_files(base, tmp_path, capsys):
    """It overwrote rgb.txt, depth.txt, groundtruth.txt and camera.txt of an existing
    sequence and left the old images beside the new lists."""
    seq = copy_seq(base, tmp_path / "seq")
    before = digest_folder(seq)
    res = cli(capsys, "synth", "handheld_fast", seq, "--frames", "2")
    assert_one_line_error(res, "OUT_DIR", "is not empty")
    assert digest_folder(seq) == before
    res = cli(capsys, "synth", "handheld_fast", seq, "--composite", seq, "--frames", "2")
    assert_one_line_error(res, "OUT_DIR", "which this command reads")
    assert digest_folder(seq) == before
    (tmp_path / "empty").mkdir()  # an empty folder is a new one
    assert cli(capsys, "synth", "static", tmp_path / "empty", "--frames", "2").rc == 0
    assert (tmp_path / "empty" / "rgb.txt").is_file()


def test_demo_outputs_are_distinct_files(tmp_path, capsys):
    res = cli(capsys, "demo", "--frames", "3", "--peers", "opencv_rgb,opencv_rgb",
              "--out", tmp_path / "d")
    assert_one_line_error(res, "the opencv_rgb trajectory (#4) and the opencv_rgb trajectory "
                          "(#3) are the same file")
    assert not (tmp_path / "d").exists()


def test_study_results_never_go_over_the_spec_or_a_sequence(base, tmp_path, capsys):
    spec = tmp_path / "spec.json"  # what a study writes as its record in --out
    spec.write_text(json.dumps({"sequences": [{"path": str(base), "frames": 3}]}))
    before = spec.read_bytes()
    assert_one_line_error(cli(capsys, "study", spec, "--out", tmp_path, "-q"),
                          "--out", "spec.json, which this command reads")
    assert spec.read_bytes() == before
    assert_one_line_error(cli(capsys, "study", spec, "--out", tmp_path / "r", "--flow-cache",
                              base, "-q"), "--flow-cache", "which this command reads")
    assert not (tmp_path / "r").exists()


def test_check_outputs_refuses_one_file_twice(tmp_path):
    from jaxvo.host.readers.io import check_outputs

    with pytest.raises(InputError, match="b and a are the same file"):
        check_outputs((), files={"a": tmp_path / "t.txt", "b": tmp_path / "." / "t.txt"})
    check_outputs([tmp_path / "in.txt"], files={"a": tmp_path / "t.txt"},
                  folders={"m": tmp_path / "m"})  # apart: fine


def test_out_dash_writes_the_trajectory_to_standard_output(base, tmp_path, capsys):
    """--out - wrote a file named '-'; now the trajectory goes to stdout (as command-line
    tools do) and the summary to stderr."""
    res = cli(capsys, "run", base, "--out", "-", "-q", "--json")
    assert res.rc == 0, res.err
    assert not Path("-").exists()
    piped = tmp_path / "piped.txt"
    piped.write_text(res.out)
    summary = json.loads("\n".join(res.err))
    assert summary["trajectory"] == "-" and summary["poses_written"] == FRAMES
    assert "ate_rmse_m" in summary  # scored from the poses written
    assert cli(capsys, "run", base, "--out", tmp_path / "file.txt", "-q").rc == 0
    np.testing.assert_array_equal(read_trajectory(piped).poses,
                                  read_trajectory(tmp_path / "file.txt").poses)
    text = cli(capsys, "run", base, "--out", "-", "-q")
    assert text.rc == 0 and "poses -> standard output" in "\n".join(text.err)
    assert text.out.startswith("# jaxvo run") and "ATE" not in text.out


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (Linux)")
def test_a_full_disk_names_the_file(base, tmp_path, capfd):
    """'No space left on device' named no file; libpng added 'libpng error: Write Error'."""
    rc = main(["run", str(base), "--out", "/dev/full", "-q"])
    err = [ln for ln in capfd.readouterr().err.splitlines() if ln.strip()]
    assert rc == 2 and err == ["jaxvo: error: /dev/full: No space left on device"], err
    masks = tmp_path / "masks"
    masks.mkdir()
    for t in read_trajectory(base / "groundtruth.txt").timestamps:
        (masks / f"{t:.6f}.png").symlink_to("/dev/full")  # every mask lands on a full disk
    rc = main(["run", str(base), "--out", str(tmp_path / "t.txt"), "--masks", str(masks), "-q"])
    err = [ln for ln in capfd.readouterr().err.splitlines() if ln.strip()]
    assert rc == 2 and len(err) == 1, err
    assert re.fullmatch(r"jaxvo: error: .*/masks/\d+\.\d{6}\.png: No space left on device",
                        err[0]), err


def test_rerun_save_onto_an_input_or_into_an_unwritable_folder(base, tmp_path, unwritable,
                                                              capsys):
    seq = copy_seq(base, tmp_path / "seq")
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt", "--rerun-save",
                              seq / "rgb.txt"), "--rerun-save", "would overwrite the input")
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt", "--rerun-save",
                              unwritable / "run.rrd"), "--rerun-save", "cannot write")
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt", "--map",
                              seq / "rgb.txt"), "--map", "would overwrite the input")
    assert not (tmp_path / "t.txt").exists()  # refused before any work


def test_no_file_of_the_sequence_can_be_an_output(base, tmp_path, capsys):
    """Only the frames a run read were protected: --frames 2 --out SEQ/rgb/<3rd image> filled
    an image with the trajectory, --map SEQ/rgb/<image>.ply its picture; a hard link to the
    ground truth was written through."""
    seq = copy_seq(base, tmp_path / "seq", images=("rgb",))
    shutil.copy(seq / "rgb" / min(os.listdir(seq / "rgb")), seq / "rgb" / "unlisted.png")
    images = sorted((seq / "rgb").iterdir())
    before = {p: p.read_bytes() for p in images}
    assert_one_line_error(cli(capsys, "run", seq, "--frames", 2, "--out", images[2]),
                          "--out", "would overwrite the input")
    assert_one_line_error(cli(capsys, "run", seq, "--out", seq / "rgb" / "unlisted.png"),
                          "--out", "would overwrite a file of the input folder")
    assert_one_line_error(cli(capsys, "run", seq, "--frames", 2, "--out", tmp_path / "t.txt",
                              "--map", images[3].with_suffix(".ply")),
                          "--map's map picture", "would overwrite the input")
    os.link(seq / "groundtruth.txt", tmp_path / "hard.txt")
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "hard.txt"),
                          "would overwrite the input", "groundtruth.txt")
    for option in ("--rerun-save", "--map"):  # wrote files named '-'
        assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt", option, "-"),
                              f"{option} -: {option} writes a file, not standard output")
    assert {p: p.read_bytes() for p in images} == before and not Path("-").exists()
    assert not (tmp_path / "t.txt").exists()


def test_out_dev_stdout_is_standard_output_written_once(base, capfd):
    """``--out /dev/stdout > f``: the summary, printed to the same file after the
    trajectory, overwrote it."""
    rc = main(["run", str(base), "--out", "/dev/stdout", "-q"])
    cap = capfd.readouterr()
    assert rc == 0 and cap.out.startswith("# jaxvo run") and "jaxvo run:" not in cap.out
    assert len(read_trajectory_text(cap.out)) == FRAMES
    assert "poses -> standard output" in cap.err


def read_trajectory_text(text: str):
    return read_trajectory("-", text=text)


def test_a_closed_or_broken_standard_output(base, capsys, monkeypatch):
    """``--out - >&-`` raised AttributeError: 'NoneType' object has no attribute 'write';
    ``--out - | head`` ended 'jaxvo: error: -: Broken pipe', exit 2."""
    import errno

    from jaxvo.host.writers import outputs

    monkeypatch.setattr(outputs, "STDOUT_CLOSED", False)
    monkeypatch.setattr(sys, "stdout", None)
    rc = main(["run", str(base), "--out", "-", "-q"])
    assert rc == 2 and "--out -: standard output is closed" in capsys.readouterr().err

    class ReaderGone:
        def write(self, text):
            raise BrokenPipeError(errno.EPIPE, "Broken pipe")

        flush = write

    monkeypatch.setattr(outputs, "STDOUT_CLOSED", False)
    monkeypatch.setattr(sys, "stdout", ReaderGone())
    rc = main(["run", str(base), "--out", "-", "-q"])
    assert rc == 141 and capsys.readouterr().err == ""  # quiet, as other tools end
