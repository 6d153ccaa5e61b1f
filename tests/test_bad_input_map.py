"""Bad input at jaxvo map: a trajectory of another sequence, its options and outputs.

Each refused in one line before any map is fused.

The answers every case expects and the sequence each breaks: tests/bad_input.py.
"""

from __future__ import annotations

from bad_input import FRAMES, assert_one_line_error, base, cli, unwritable  # noqa: F401 (fixtures)


def test_map_with_a_trajectory_of_another_sequence(base, tmp_path, capsys):
    lines = [f"{1000.0 + i / 30:.6f} 0 0 0 0 0 0 1" for i in range(FRAMES)]
    (tmp_path / "other.txt").write_text("\n".join(lines) + "\n")
    res = cli(capsys, "map", base, "--traj", tmp_path / "other.txt", "--out", tmp_path / "m.ply")
    assert_one_line_error(res, "--traj", "another sequence")
    assert not (tmp_path / "m.ply").exists()


def test_map_options_and_outputs_are_checked_first(base, tmp_path, unwritable, capsys):
    traj = tmp_path / "t.txt"
    traj.write_text("0.0 0 0 0 0 0 0 1\n")
    for args, needles in ((("--voxel", "0"), ("--voxel",)), (("--vote-share", "2"),
                                                             ("--vote-share",)),
                          (("--grow", "-1"), ("--grow",)),
                          (("--dynamic-masks", tmp_path / "none"), ("--dynamic-masks",))):
        assert_one_line_error(cli(capsys, "map", base, "--traj", traj, "--out",
                                  tmp_path / "m.ply", *args), *needles)
    assert_one_line_error(cli(capsys, "map", base, "--traj", traj, "--out",
                              unwritable / "m.ply"), "--out", "cannot write")
    assert_one_line_error(cli(capsys, "map", base, "--traj", traj, "--out", traj),
                          "--out", "would overwrite the input")
