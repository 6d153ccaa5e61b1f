"""Bad input at the Python API: what OpenCV, Open3D, NumPy and ROS users pass.

``Odometry`` and ``run_sequence`` take the depth types, cameras and times users hold, and
refuse the rest with a ``ValueError`` that says what is wrong.

The answers every case expects and the sequence each breaks: tests/bad_input.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from bad_input import FRAMES, base, base_seq  # noqa: F401 (fixtures)

from jaxvo.config import Config, Params
from jaxvo.errors import InputError
from jaxvo.evaluation.metrics import ate
from jaxvo.host.frontend.camera import Intrinsics
from jaxvo.odometry import Odometry
from jaxvo.status import Status


def poses_of(odo: Odometry, frames, depth_of) -> np.ndarray:
    for f in frames:
        odo.process(f.bgr, depth_of(f), f.timestamp)
    return odo.trajectory.poses


def test_odometry_takes_uint16_depth_with_the_depth_scale(base_seq):
    """cv2.imread(..., IMREAD_UNCHANGED) gives uint16 raw units; before, every frame came
    back 'unreadable' with an identity pose. The result equals float metres bit for bit."""
    K = base_seq.intrinsics  # depth_scale 5000 per metre
    frames = list(base_seq)[:3]
    raw = [np.round(f.depth.astype(np.float64) * K.depth_scale).astype(np.uint16) for f in frames]
    by_raw = poses_of(Odometry(K), frames, lambda f: raw[f.index])
    metres = [r.astype(np.float32) / np.float32(K.depth_scale) for r in raw]
    by_metres = poses_of(Odometry(K), frames, lambda f: metres[f.index])
    np.testing.assert_array_equal(by_raw, by_metres)
    assert not np.allclose(by_raw[-1], np.eye(4), atol=1e-3)  # the camera moved
    by_f64 = poses_of(Odometry(K), frames, lambda f: metres[f.index].astype(np.float64))
    np.testing.assert_array_equal(by_f64, by_metres)


@pytest.mark.parametrize(
    "bgr, depth, needle",
    [
        (lambda f: f.bgr, lambda f: f.depth.astype(np.int32), "got int32"),
        (lambda f: f.bgr, lambda f: f.depth[..., None], r"depth must be an \(H, W\) image"),
        (lambda f: f.bgr.astype(np.float32) / 255, lambda f: f.depth, "uint8 BGR image"),
        (lambda f: f.bgr[..., None], lambda f: f.depth, "uint8 BGR image"),
        (lambda f: f.bgr, lambda f: f.depth[:240], "differ in size"),
        (lambda f: None, lambda f: f.depth, "got NoneType"),
    ],
)
def test_odometry_refuses_wrong_dtype_or_shape(base_seq, bgr, depth, needle):
    f = base_seq[0]
    with pytest.raises(ValueError, match=needle):
        Odometry(base_seq.intrinsics).process(bgr(f), depth(f), f.timestamp)


def test_odometry_refuses_time_going_back_and_bad_settings(base_seq):
    f0, f1 = base_seq[0], base_seq[1]
    K = base_seq.intrinsics
    odo = Odometry(K)
    odo.process(f0.bgr, f0.depth, 1.0)
    with pytest.raises(ValueError, match="does not follow the previous frame's 1.000000 s"):
        odo.process(f1.bgr, f1.depth, 1.0)
    with pytest.raises(ValueError, match="finite"):
        odo.process(f1.bgr, f1.depth, float("nan"))
    with pytest.raises(ValueError, match="fx is nan"):
        Odometry(K._replace(fx=float("nan")))
    with pytest.raises(ValueError, match="Config.cell must be at least 4"):
        Odometry(K, cfg=Config(cell=0))
    with pytest.raises(ValueError, match=r"Params.confidence must be in \(0, 1\), got 1"):
        Odometry(K, params=Params(confidence=1.0))
    with pytest.raises(ValueError, match="T_w_c0 is not a rigid transform"):
        Odometry(K, T_w_c0=np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="principal point"):
        Odometry(K._replace(cx=3195.0)).process(f0.bgr, f0.depth, 0.0)


def test_odometry_starts_at_the_given_pose(base_seq):
    f0 = base_seq[0]
    T0 = np.eye(4)
    T0[:3, 3] = [1.0, -2.0, 0.5]
    odo = Odometry(base_seq.intrinsics, T_w_c0=T0)
    np.testing.assert_array_equal(odo.process(f0.bgr, f0.depth, 0.0).T_w_c, T0)


def test_a_useless_frame_costs_its_own_pose_only(base_seq):
    """Streaming: a black frame is dropped (no pose, the reason said) and the next frame
    pairs with the last good one; the trajectory over the kept frames is about as accurate
    as without the black frame, instead of carrying two pairs' motion as identity."""
    gt, K = base_seq.groundtruth, base_seq.intrinsics
    clean = Odometry(K, T_w_c0=gt.poses[0])
    odo = Odometry(K, T_w_c0=gt.poses[0])
    results = []
    for f in base_seq:
        clean.process(f.bgr, f.depth, f.timestamp)
        bgr = np.zeros_like(f.bgr) if f.index == 2 else f.bgr
        results.append(odo.process(bgr, f.depth, f.timestamp))
    assert results[2].dropped and results[2].status == Status.BAD_INPUT
    assert all(r.dropped is None for k, r in enumerate(results) if k != 2)
    assert results[3].status == Status.OK  # frame 3 paired with frame 1
    assert len(odo.trajectory) == FRAMES - 1
    e_clean = ate(gt, clean.trajectory, align=False).stats.rmse
    e_drop = ate(gt, odo.trajectory, align=False).stats.rmse
    # measured (not aligned, both from the true first pose): clean 0.29 mm, dropped 0.21 mm;
    # before, the two pairs touching the black frame carried as identity: 2.1 mm
    assert e_drop < e_clean + 0.0005, (e_drop, e_clean)  # within 0.5 mm of the clean run


def test_odometry_refuses_float_depth_in_millimetres_or_raw_units(base_seq):
    f = base_seq[0]
    K = base_seq.intrinsics
    for depth, what in ((f.depth * 1000, "millimetres"), (f.depth * K.depth_scale, "raw")):
        with pytest.raises(ValueError, match="median of the float depth is .* the depth scale "
                                             "looks wrong"):
            Odometry(K).process(f.bgr, depth, f.timestamp)
    mm = np.round(f.depth * 1000).astype(np.uint16)  # millimetres at 5000 per metre
    odo = Odometry(K)
    from jaxvo.host.readers.io import DepthScaleWarning

    with pytest.warns(DepthScaleWarning, match="depth_scale 1000 is likelier"):
        odo.process(f.bgr, mm, f.timestamp)
    assert len(odo.warnings) == 1


def test_odometry_takes_a_tuple_a_dict_a_camera_matrix_or_a_preset(base_seq):
    K = Intrinsics(525.0, 525.0, 319.5, 239.5, 5000.0)
    for given in ((525, 525, 319.5, 239.5), [525, 525, 319.5, 239.5, 5000],
                  {"fx": 525, "fy": 525, "cx": 319.5, "cy": 239.5}, K.matrix(), np.asarray(K[:4]),
                  "ros_default"):
        assert Odometry(given).intrinsics == K, given
    for bad, needle in (((525, 525), "got shape"), ({"fx": 525, "f": 1}, "got keys"),
                        (object(), "got object"), (np.ones((3, 3)), "a camera matrix is"),
                        ("tum_fr9", "unknown camera preset")):
        with pytest.raises(ValueError, match=needle):
            Odometry(bad)


def test_run_sequence_takes_a_folder_and_says_what_it_expects(base, base_seq):
    from jaxvo.odometry import _as_sequence, run_sequence

    seq = _as_sequence(str(base))
    assert len(seq) == FRAMES and seq.intrinsics == base_seq.intrinsics
    assert _as_sequence(base_seq) is base_seq
    with pytest.raises(ValueError, match="for frames in a list, feed them to jaxvo.Odometry"):
        run_sequence(list(base_seq))
    with pytest.raises(InputError, match="sequence folder not found"):
        run_sequence(str(base / "missing"))


def test_odometry_takes_infinite_and_float64_depth_as_no_reading(base_seq):
    """Float64 depth beyond float32 and +inf are no reading, with no overflow warning."""
    import warnings

    f = base_seq[0]
    depth = f.depth.astype(np.float64)
    depth[:10] = np.inf
    depth[10:20] = 1e300
    odo = Odometry(base_seq.intrinsics)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = odo.process(f.bgr, depth, f.timestamp)
    assert r.dropped is None and odo.warnings == []


def test_odometry_takes_the_times_numpy_and_ros_users_hold(base_seq):
    """np.datetime64 was taken as seconds and came out as nanoseconds written as seconds."""
    from types import SimpleNamespace

    from jaxvo.trajectory import timestamp_seconds

    t_ns = 1305031102175304000
    for t in (np.datetime64(t_ns, "ns"), np.datetime64(t_ns // 1000, "us"), t_ns,
              np.int64(t_ns), SimpleNamespace(sec=1305031102, nanosec=175304000),
              SimpleNamespace(secs=1305031102, nsecs=175304000)):
        assert abs(timestamp_seconds(t) - 1305031102.175304) < 1e-6, t  # tol 1 us
    assert timestamp_seconds(np.timedelta64(1500, "ms")) == pytest.approx(1.5, abs=1e-12)
    assert timestamp_seconds(12) == 12.0 and timestamp_seconds(np.float32(0.5)) == 0.5
    for bad, needle in ((1305031102175, "neither seconds nor nanoseconds"),
                        ("1.0", "got str"), (True, "got bool"), (None, "got NoneType"),
                        (np.datetime64("NaT"), "NaT"), (float("inf"), "finite")):
        with pytest.raises(ValueError, match=needle):
            timestamp_seconds(bad)
    odo = Odometry(base_seq.intrinsics)
    for k in range(2):
        f = base_seq[k]
        odo.process(f.bgr, f.depth, np.datetime64(t_ns + k * 33_000_000, "ns"))
    np.testing.assert_allclose(odo.trajectory.timestamps, [1305031102.175304, 1305031102.208304],
                               atol=1e-6)  # tol 1 us


def test_a_date_past_2262_is_not_wrapped():
    """np.datetime64 went through nanoseconds, which hold dates up to 2262: 2300 came back
    as about 1830 and was taken."""
    from jaxvo.trajectory import timestamp_seconds

    want = (np.datetime64("2300-01-01", "D") - np.datetime64("1970-01-01", "D")).astype(int)
    for t in (np.datetime64("2300-01-01", "D"), np.datetime64("2300-01-01T00:00:00", "s")):
        assert timestamp_seconds(t) == pytest.approx(float(want) * 86400.0, abs=1e-3)  # 1 ms
    with pytest.raises(ValueError, match="beyond any recording"):
        timestamp_seconds(np.datetime64("9999-01-01", "D"))
