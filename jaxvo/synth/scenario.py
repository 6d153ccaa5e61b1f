"""What a synthetic scene is made of (host): the moving boxes, the camera's motion, the
sensor's effects, and the presets of thesis Table 5.1 (``SCENARIOS``).

Plain frozen dataclasses; :mod:`jaxvo.synth.sequence` renders them and
:mod:`jaxvo.synth.scenes` turns a preset's name into a sequence.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

# ----------------------------------------------------------------------------- options


@dataclass(frozen=True)
class SensorOptions:
    """Sensor effects, each switchable; :meth:`ideal` turns them all off.

    Attributes:
      depth_noise: add Gaussian depth noise with sigma = ``depth_noise_coeff * z**2``
        (Khoshelham and Elberink 2012 give 1.425e-3 / m for the Kinect).
      edge_holes: no reading along depth discontinuities (object silhouettes, furniture
        edges), a band about three pixels wide.
      depth_range: no reading outside ``[min_depth, max_depth]`` metres.
      colour_noise: Gaussian colour noise of ``colour_sigma`` 8-bit levels.
      motion_blur: average the colour over ``blur_samples`` instants spread over
        ``exposure`` frame intervals (the depth stays instantaneous).
      exposure_change: a slow auto-exposure drift of the colour gain,
        ``1 +- exposure_amplitude`` over ``exposure_period`` seconds.
    """

    depth_noise: bool = True
    depth_noise_coeff: float = 1.425e-3
    edge_holes: bool = True
    depth_range: bool = True
    min_depth: float = 0.5
    max_depth: float = 3.5
    colour_noise: bool = True
    colour_sigma: float = 2.0
    motion_blur: bool = False
    blur_samples: int = 5
    exposure: float = 0.5
    exposure_change: bool = False
    exposure_amplitude: float = 0.2
    exposure_period: float = 4.0

    @classmethod
    def ideal(cls) -> SensorOptions:
        """No noise, no holes, no range limit, no blur, constant exposure."""
        return cls(depth_noise=False, edge_holes=False, depth_range=False,
                   colour_noise=False, motion_blur=False, exposure_change=False)

    def _model(self):
        from jaxvo.synth.render import SensorModel

        return SensorModel(
            depth_noise=self.depth_noise_coeff if self.depth_noise else 0.0,
            edge_holes=self.edge_holes,
            min_depth=self.min_depth if self.depth_range else 0.0,
            max_depth=self.max_depth if self.depth_range else float("inf"),
            colour_sigma=self.colour_sigma if self.colour_noise else 0.0,
        )


# --------------------------------------------------------------------------- scenarios


@dataclass(frozen=True)
class ObjectSpec:
    """A moving rigid box: size and a Lissajous path around a centre, spinning.

    Position ``centre + amplitude * sin(2 pi t / period + phase)`` per axis (world frame,
    metres, seconds); rotation about a seeded axis at ``spin`` rad/s. ``phase`` ``None``
    draws the phases from the seed. ``stops`` are ``(start, end)`` intervals in seconds
    from the first frame during which the box holds still (its path's clock stops), so
    an object can stop and start again. ``follow`` makes the path relative to the camera:
    ``centre`` and the path are then in the frame of the camera pose averaged over
    ``follow`` seconds (0: the camera itself), so a box can stay in view, moving with the
    camera and across it; ``None`` keeps the default frame (the world in a synthetic room,
    the camera path smoothed over 3 s in a composite).
    """

    size: tuple[float, float, float]
    centre: tuple[float, float, float]
    amplitude: tuple[float, float, float]
    period: tuple[float, float, float]
    spin: float = 0.4
    phase: tuple[float, float, float] | None = None
    stops: tuple[tuple[float, float], ...] = ()
    follow: float | None = None


@dataclass(frozen=True)
class Scenario:
    """A scene preset: camera motion and moving objects.

    ``camera`` is ``"fixed"`` (at the origin, looking at ``look_at``) or ``"handheld"``
    (a smooth seeded path of mean speed ``camera_speed`` m/s around the origin, looking at
    ``look_at`` with a small wander).
    """

    name: str
    description: str
    camera: str = "handheld"
    camera_speed: float = 0.2
    objects: tuple[ObjectSpec, ...] = ()
    look_at: tuple[float, float, float] = (0.0, 0.2, 2.0)
    camera_wander: float = 1.0  # scales the path's extent (amplitude per unit speed)


def _heavy_cover(percent: int, size: tuple[float, float, float], distance: float) -> Scenario:
    """One near box covering about ``percent`` % of the view from the first frame and
    staying in view: it follows the camera (its path averaged over 1 s, so it lags when
    the camera turns) and drifts across the view, spinning slowly. ``distance`` is the
    box's centre in front of the camera, metres."""
    return Scenario(
        f"heavy_cover_{percent}",
        f"a near box covering about {percent} % of the view from the first frame, moving "
        "with the camera and across it",
        camera="handheld", camera_speed=0.15,
        objects=(ObjectSpec(size=size, centre=(0.0, 0.0, distance),
                            amplitude=(0.08, 0.04, 0.05), period=(4.3, 3.7, 5.1), spin=0.08,
                            follow=1.0),))


def _carried(percent: int, size: tuple[float, float, float]) -> Scenario:
    """One near box covering about ``percent`` % of the view from the first frame, carried
    with the camera: its path is in the camera's own frame (``follow`` 0), so its motion
    relative to the camera is only its slow drift across the view (about 0.1-0.16 m/s)
    and a slow turn, while the world behind it moves with the camera. Its front face is
    about 0.6 m away, the room 1-3 m."""
    return Scenario(
        f"carried_{percent}",
        f"a near box covering about {percent} % of the view from the first frame, carried "
        "with the camera and drifting slowly across the view",
        camera="handheld", camera_speed=0.15,
        objects=(ObjectSpec(size=size, centre=(0.0, 0.0, 0.6 + size[2] / 2),
                            amplitude=(0.14, 0.04, 0.03), period=(6.0, 4.7, 5.5), spin=0.08,
                            follow=0.0),))


_CUBE = ObjectSpec(size=(0.36, 0.36, 0.36), centre=(0.0, 0.15, 1.7),
                   amplitude=(0.65, 0.15, 0.3), period=(4.6, 3.7, 6.3), spin=0.6)

SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        Scenario(
            "fixed_camera_1", "static camera, one box moving in front of it (Fixed Camera 1)",
            camera="fixed", camera_speed=0.0, objects=(_CUBE,),
        ),
        Scenario(
            "fixed_camera_2",
            "static camera, two boxes; the near one swings close and together they cover "
            "more than half the image at times (Fixed Camera 2)",
            camera="fixed", camera_speed=0.0,
            objects=(
                ObjectSpec(size=(0.62, 0.55, 0.24), centre=(-0.1, 0.15, 1.25),
                           amplitude=(0.35, 0.1, 0.5), period=(5.3, 4.1, 3.2), spin=0.25,
                           phase=(0.0, 1.0, 0.5 * np.pi)),
                ObjectSpec(size=(0.5, 0.5, 0.5), centre=(0.2, 0.1, 2.3),
                           amplitude=(0.75, 0.15, 0.2), period=(3.9, 5.1, 4.4), spin=0.5),
            ),
        ),
        Scenario(
            "handheld_fast", "hand-held camera moving fast (about 0.33 m/s) and one box "
            "(Vicon Room 1)", camera="handheld", camera_speed=0.33,
            objects=(replace(_CUBE, size=(0.4, 0.5, 0.3), amplitude=(0.5, 0.12, 0.3)),),
        ),
        Scenario(
            "handheld_slow", "hand-held camera moving slowly (about 0.16 m/s) and one box "
            "(Vicon Room 2)", camera="handheld", camera_speed=0.16,
            objects=(replace(_CUBE, amplitude=(0.5, 0.12, 0.3)),),
        ),
        Scenario(
            "close_approach",
            "slow hand-held camera; a box comes to about 0.3 m, inside the sensor's 0.5 m "
            "minimum range, and leaves again (Vicon Room 3)",
            camera="handheld", camera_speed=0.1, camera_wander=0.6,
            objects=(
                ObjectSpec(size=(0.4, 0.4, 0.3), centre=(0.0, 0.12, 1.25),
                           amplitude=(0.2, 0.06, 0.8), period=(5.0, 4.0, 4.0), spin=0.3,
                           phase=(0.0, 0.0, 0.5 * np.pi)),
            ),
        ),
        Scenario(
            "static", "hand-held camera (about 0.2 m/s) in the room, nothing moves: the "
            "control", camera="handheld", camera_speed=0.2,
        ),
        # built for composites into real frames (the evaluation's failure cases); the
        # camera settings apply when rendered fully synthetic
        Scenario(
            "three_boxes",
            "three boxes that together cover about half the view, swinging in front of a "
            "hand-held camera", camera="handheld", camera_speed=0.15,
            objects=(
                ObjectSpec(size=(0.55, 0.5, 0.35), centre=(-0.45, 0.05, 1.5),
                           amplitude=(0.25, 0.1, 0.2), period=(4.1, 3.3, 5.2), spin=0.35),
                ObjectSpec(size=(0.5, 0.55, 0.4), centre=(0.5, 0.0, 1.7),
                           amplitude=(0.2, 0.12, 0.25), period=(3.6, 4.4, 4.9), spin=0.3),
                ObjectSpec(size=(0.4, 0.4, 0.4), centre=(0.0, 0.35, 1.3),
                           amplitude=(0.3, 0.08, 0.15), period=(4.8, 3.9, 4.2), spin=0.45),
            ),
        ),
        Scenario(
            "enter_leave",
            "two boxes that sweep in from one side of the view and out at the other",
            camera="handheld", camera_speed=0.15,
            objects=(
                # about 1 m/s at the centre of the view, as a person walking past
                ObjectSpec(size=(0.45, 0.45, 0.4), centre=(0.0, 0.1, 1.5),
                           amplitude=(1.3, 0.1, 0.15), period=(8.0, 3.1, 3.7), spin=0.4,
                           phase=(-0.5 * np.pi, 0.0, 0.0)),
                ObjectSpec(size=(0.4, 0.5, 0.35), centre=(0.1, -0.1, 1.9),
                           amplitude=(0.2, 1.0, 0.2), period=(3.4, 7.0, 4.1), spin=0.3,
                           phase=(0.0, 0.5 * np.pi, 1.0)),
            ),
        ),
        Scenario(
            "stop_start",
            "two boxes; one stops for a while, moves again and stops again",
            camera="handheld", camera_speed=0.15,
            objects=(
                ObjectSpec(size=(0.5, 0.5, 0.4), centre=(-0.25, 0.1, 1.5),
                           amplitude=(0.4, 0.1, 0.25), period=(4.4, 3.5, 5.1), spin=0.4,
                           stops=((1.0, 2.3), (3.3, 4.3))),
                ObjectSpec(size=(0.35, 0.35, 0.35), centre=(0.45, 0.2, 1.8),
                           amplitude=(0.25, 0.1, 0.2), period=(3.9, 4.6, 4.3), spin=0.5),
            ),
        ),
        # the heavy-cover family: a near mover filling the view, from which the camera's
        # motion must not be taken because it has the most points
        _heavy_cover(50, (0.76, 0.58, 0.3), 1.05),
        _heavy_cover(70, (0.87, 0.65, 0.3), 1.0),
        _heavy_cover(90, (0.95, 0.72, 0.3), 0.9),
        # the carried family: a near box moving with the camera itself, so that in the
        # first frames its motion and the world's are one within the noise of a pair
        _carried(50, (0.46, 0.36, 0.2)),
        _carried(70, (0.56, 0.43, 0.2)),
    )
}
