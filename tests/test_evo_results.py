"""``jaxvo eval --save_results / --plot`` against evo itself: evo reads jaxvo's result zips,
``evo_res`` compares them with the zips ``evo_ape`` / ``evo_rpe`` wrote, and the numbers in
both agree on the same files.

evo runs in child processes with ``HOME`` in the test's folder (it writes its settings
there on first use). The tests that need evo skip, naming it, where it is not installed.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from jaxvo.cli.main import main
from jaxvo.evaluation.metrics import ate
from jaxvo.host.readers.io import write_trajectory
from jaxvo.trajectory import Trajectory, read_trajectory
from jaxvo.transforms import pose_from_tq

# evo's cases beside jaxvo's: (jaxvo eval argv after the files, evo command, evo's flags)
CASES = {
    "ape_se3": (["ate", "-a"], "evo_ape", ["-a"]),
    "ape_unaligned": (["ate", "--no-align"], "evo_ape", []),
    "ape_sim3": (["ate", "-as"], "evo_ape", ["-as"]),
    "ape_scale_only": (["ate", "-s"], "evo_ape", ["-s"]),
    "rpe_30f": (["rpe", "-a", "--delta", "30", "--delta_unit", "f"], "evo_rpe",
                ["-a", "--delta", "30", "--delta_unit", "f"]),
    "rpe_rot_all": (["rpe", "-r", "angle_deg", "--delta", "5", "--all_pairs"], "evo_rpe",
                    ["-r", "angle_deg", "--delta", "5", "--all_pairs"]),
}


@pytest.fixture
def pair(tmp_path, random_groundtruth):
    """A ground truth and an estimate with drift, scale error 1.1 and a rigid offset."""
    rng = np.random.default_rng(1)
    n = 60
    gt = random_groundtruth(rng, n, 5.0)
    t = gt.timestamps
    drift = pose_from_tq(np.cumsum(rng.normal(size=(n, 3)) * 0.002, 0), [0, 0, 0, 1])
    est_poses = pose_from_tq([0.3, -0.2, 0.1], [0.1, 0.0, 0.2, 0.97]) @ gt.poses @ drift
    est_poses[:, :3, 3] *= 1.1
    write_trajectory(tmp_path / "gt.txt", gt)
    write_trajectory(tmp_path / "est.txt", Trajectory(t + 0.004, est_poses))
    return tmp_path / "gt.txt", tmp_path / "est.txt"


def jaxvo_eval(capsys, *argv):
    code = main(["eval", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


def test_zip_holds_evos_layout(pair, tmp_path, capsys):
    """The zip's members, info and numbers, read back with zipfile and numpy alone."""
    gt, est = pair
    out = tmp_path / "r.zip"
    code, stdout, _ = jaxvo_eval(capsys, "ate", gt, est, "--save_results", out, "--json")
    assert code == 0
    with zipfile.ZipFile(out) as z:
        names = set(z.namelist())
        info = json.loads(z.read("info.json"))
        stats = json.loads(z.read("stats.json"))
        arrays = {n[:-4]: np.load(z.open(n)) for n in names if n.endswith(".npy")}
    assert names == {"info.json", "stats.json", "error_array.npy", "seconds_from_start.npy",
                     "timestamps.npy", "distances_from_start.npy", "distances.npy",
                     "alignment_transformation_sim3.npy"}
    assert info == {"title": "APE w.r.t. translation part (m)\n(with SE(3) Umeyama alignment)",
                    "ref_name": str(gt), "est_name": str(est), "label": "APE (m)"}
    res = ate(read_trajectory(gt), read_trajectory(est), max_diff=0.02)
    np.testing.assert_array_equal(arrays["error_array"], res.errors)  # the same numbers
    report = json.loads(stdout)["results"]["trans"]
    assert {k: report[k] for k in stats} == stats
    # evo's timestamps are the estimate's (0.004 s after the ground truth's here)
    np.testing.assert_allclose(arrays["timestamps"], res.timestamps + 0.004, atol=1e-6)
    np.testing.assert_allclose(arrays["alignment_transformation_sim3"],
                               res.alignment.matrix(), atol=0)


def test_plot_writes_an_image(pair, tmp_path, capsys):
    pytest.importorskip("matplotlib", reason="the plot extra (matplotlib) is not installed")
    gt, est = pair
    for metric, mode in (("ate", "xyz"), ("rpe", "xy")):
        png = tmp_path / f"{metric}.png"
        code, _, err = jaxvo_eval(capsys, metric, gt, est, "--plot", png, "--plot_mode", mode)
        assert code == 0, err
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


def test_plot_without_matplotlib_is_one_line(pair, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import fails as when absent
    code, out, err = jaxvo_eval(capsys, "ate", *pair, "--plot", tmp_path / "a.png")
    assert code == 2 and out == "" and err.count("\n") == 1
    assert err.startswith("jaxvo: error: --plot needs matplotlib") and "jaxvo[plot]" in err
    assert not (tmp_path / "a.png").exists()


@pytest.mark.parametrize("argv, expect", [
    (["rpe", "--delta_unit", "m"], "--delta_unit 'm'"),
    (["rpe", "--delta_unit", "d"], "degrees, radians, metres"),
    (["ate", "--save_results", "/nonexistent/folder/r.zip"], "does not exist"),
    (["ate", "--plot", "/nonexistent/folder/a.png"], "does not exist"),
])
def test_bad_options_are_one_line(pair, capsys, argv, expect):
    code, out, err = jaxvo_eval(capsys, argv[0], *pair, *argv[1:])
    assert code == 2 and out == "" and err.count("\n") == 1, err
    assert err.startswith("jaxvo: error: ") and expect in err, err


def test_evo_option_names_mean_what_they_mean_in_evo(pair, capsys):
    """-a is jaxvo's ATE default, -as is --scale, -s alone corrects only the scale,
    --t_max_diff is --max-diff, --delta_unit f is frames."""
    gt, est = pair

    def report(*argv):
        code, out, err = jaxvo_eval(capsys, *argv, "--json")
        assert code == 0, err
        return json.loads(out)

    assert report("ate", gt, est, "-a") == report("ate", gt, est)
    assert report("ate", gt, est, "-as")["results"] == report("ate", gt, est, "--scale")["results"]
    scale_only = report("ate", gt, est, "-s")
    assert scale_only["alignment"] == "scale only (Umeyama's scale)"
    sim3 = report("ate", gt, est, "-as")
    assert sim3["alignment"] == "Sim(3) Umeyama" and scale_only["scale"] == sim3["scale"] != 1.0
    assert scale_only["results"]["trans"]["rmse"] > sim3["results"]["trans"]["rmse"]
    assert (report("rpe", gt, est, "--delta", "3", "--delta_unit", "f")
            == report("rpe", gt, est, "--delta", "3", "--delta-unit", "frames"))


def test_t_max_diff_is_max_diff(pair, capsys):
    """The estimate is 0.004 s after the ground truth: 0.003 s matches nothing."""
    code, _, err = jaxvo_eval(capsys, "ate", *pair, "--t_max_diff", "0.003")
    assert code == 2 and "no timestamps match within 0.003 s" in err


# --- against evo itself -------------------------------------------------------------------


def evo_env(tmp_path) -> dict[str, str]:
    return {**os.environ, "HOME": str(tmp_path), "MPLBACKEND": "Agg"}


def need_evo():
    pytest.importorskip("evo", reason="evo is not installed (pip install 'jaxvo[test]')")
    if shutil.which("evo_ape") is None or shutil.which("evo_res") is None:
        pytest.skip("evo's commands (evo_ape, evo_res) are not on PATH")


LOAD_BOTH = """
import json, sys
import numpy as np
from evo.tools.file_interface import load_res_file
out = {}
for name in sys.argv[1:]:
    r = load_res_file(name)
    out[name] = {"info": r.info, "stats": r.stats,
                 "arrays": {k: np.asarray(v).tolist() for k, v in r.np_arrays.items()}}
print(json.dumps(out))
"""


def test_evo_reads_jaxvo_zips_and_agrees(pair, tmp_path, capsys):
    """For each case: evo's load_res_file reads jaxvo's zip, and its info, stats and arrays
    equal those of evo's own zip on the same files."""
    need_evo()
    gt, est = pair
    zips = []
    for case, (jargs, evo_cmd, evo_flags) in CASES.items():
        ours, theirs = tmp_path / f"jaxvo_{case}.zip", tmp_path / f"evo_{case}.zip"
        code, _, err = jaxvo_eval(capsys, jargs[0], gt, est, *jargs[1:], "--t_max_diff", "0.01",
                                  "--save_results", ours)
        assert code == 0, err
        subprocess.run([evo_cmd, "tum", str(gt), str(est), *evo_flags, "--save_results",
                        str(theirs), "--no_warnings"], check=True, capture_output=True,
                       env=evo_env(tmp_path), timeout=120)
        zips += [ours, theirs]
    proc = subprocess.run([sys.executable, "-c", LOAD_BOTH, *map(str, zips)], check=True,
                          capture_output=True, text=True, env=evo_env(tmp_path), timeout=120)
    loaded = json.loads(proc.stdout)
    for case in CASES:
        ours = loaded[str(tmp_path / f"jaxvo_{case}.zip")]
        theirs = loaded[str(tmp_path / f"evo_{case}.zip")]
        assert ours["info"] == theirs["info"], case
        assert ours["stats"].keys() == theirs["stats"].keys(), case
        for k, v in theirs["stats"].items():
            assert ours["stats"][k] == pytest.approx(v, rel=1e-9, abs=1e-12), (case, k)  # tol
        assert ours["arrays"].keys() == theirs["arrays"].keys(), case
        for k, v in theirs["arrays"].items():
            if case == "ape_scale_only" and k == "alignment_transformation_sim3":
                # evo stores the whole Sim(3) fit but applies only its scale; jaxvo stores
                # what it applied: the same scale on the diagonal
                assert ours["arrays"][k][0][0] == pytest.approx(np.linalg.norm(
                    np.asarray(v)[:3, 0]), rel=1e-9)  # tol 1e-9
                continue
            np.testing.assert_allclose(ours["arrays"][k], v, rtol=1e-9, atol=1e-12,
                                       err_msg=f"{case} {k}")  # tol 1e-9 relative


def test_evo_res_compares_jaxvo_with_evo(pair, tmp_path, capsys):
    """``evo_res`` takes jaxvo's zip beside one evo_ape wrote (another estimate: evo_res
    wants distinct names) and tabulates both."""
    need_evo()
    gt, est = pair
    other = tmp_path / "other.txt"
    traj = read_trajectory(est)
    poses = traj.poses.copy()
    poses[:, :3, 3] += 0.01 * np.arange(len(poses))[:, None]
    write_trajectory(other, Trajectory(traj.timestamps, poses))
    ours, theirs = tmp_path / "jaxvo.zip", tmp_path / "evo.zip"
    assert jaxvo_eval(capsys, "ate", gt, est, "-a", "--t_max_diff", "0.01",
                      "--save_results", ours)[0] == 0
    subprocess.run(["evo_ape", "tum", str(gt), str(other), "-a", "--save_results", str(theirs),
                    "--no_warnings"], check=True, capture_output=True, env=evo_env(tmp_path),
                   timeout=120)
    table = tmp_path / "table.csv"
    proc = subprocess.run(["evo_res", str(ours), str(theirs), "--save_table", str(table),
                           "--no_warnings"], check=False, capture_output=True, text=True,
                          env=evo_env(tmp_path), timeout=120)
    assert proc.returncode == 0, proc.stderr + proc.stdout
    assert "mismatching titles" not in proc.stdout + proc.stderr
    text = table.read_text()
    rmse = ate(read_trajectory(gt), read_trajectory(est), max_diff=0.01).stats.rmse
    rows = {line.split(",")[0]: line.split(",") for line in text.splitlines()[1:]}
    assert set(rows) == {est.name, other.name}  # evo_res labels by the estimates' names
    row = rows[est.name]
    header = text.splitlines()[0].split(",")
    got = float(row[header.index("rmse")])
    assert got == pytest.approx(rmse, rel=1e-9)  # tol 1e-9: evo_res reads jaxvo's rmse
