"""The camera of the 3D pictures: orthographic, placed automatically, framed to what is drawn (numpy only).

An orthographic camera keeps one scale bar true everywhere in the picture plane. :func:`auto_camera` looks
down on the scene from the relay wall's front side (the side the sensor is on), turned sideways away from the
bulk of the hidden room, so the room and the corridor leading to the wall are both in view; :func:`frame`
then sets the picture's extent to what is drawn.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..scene import Scene
from ..scene.capture import Capture

ELEVATION_DEG = 48.0
"""Camera elevation above the horizontal: steep enough to look into a room with its ceiling cut away,
shallow enough to keep walls and pillars readable as upright."""

AZIMUTH_DEG = 50.0
"""Camera azimuth away from the relay wall's normal, toward the side opposite the bulk of the hidden room
(the corridor and the room beside it both show; straight down the corridor they would overlap)."""

FRAME_PAD = 0.04
"""Empty margin around the drawn scene, as a fraction of the picture's width or height."""

MIN_SIZE = 1e-3
"""Smallest scene size and picture half-extent, m (a degenerate scene still gets a camera)."""


def safe_unit(v: np.ndarray) -> np.ndarray:
    """``v`` (..., 3) divided by its norm over the last axis; zero rows stay zero (not NaN)."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def scene_size(scene: Scene) -> float:
    """Length of the diagonal of the scene's bounding box, m (at least :data:`MIN_SIZE`)."""
    b = scene.bounds()
    return float(max(np.linalg.norm(b[1] - b[0]), MIN_SIZE))


@dataclass(frozen=True)
class ViewCamera:
    """An orthographic camera.

    Attributes:
        target: (3,) float64 m, the point looked at; eye: (3,) camera position (target − forward·distance).
        forward, right, up: (3,) unit vectors of the camera frame (right = forward × up_world, up = right ×
            forward).
        extent: (left, right, bottom, top) metres of the picture in the camera's right/up coordinates, relative
            to the eye (set by :func:`frame`; None before).
        near, far: clip distances along forward, m.
    """

    target: np.ndarray
    eye: np.ndarray
    forward: np.ndarray
    right: np.ndarray
    up: np.ndarray
    extent: tuple[float, float, float, float] | None = None
    near: float = 0.01
    far: float = 100.0

    def camera_coords(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) world points → (..., 3) (right, up, depth along forward) relative to the eye, metres."""
        rel = np.asarray(points, dtype=np.float64) - self.eye
        return np.stack([rel @ self.right, rel @ self.up, rel @ self.forward], axis=-1)

    def metres_per_pixel(self, width: int) -> float:
        """Metres of the picture plane per pixel of a picture ``width`` pixels wide (needs an extent)."""
        return (self.extent[1] - self.extent[0]) / width

    def pixel_of(self, points: np.ndarray, width: int, height: int) -> np.ndarray:
        """(..., 3) world points → (..., 2) float64 (column, row) pixel coordinates of a ``width`` × ``height``
        picture of this camera (needs an extent; pixel centres at +0.5)."""
        c = self.camera_coords(points)
        left, right, bottom, top = self.extent
        return np.stack([(c[..., 0] - left) / (right - left) * width,
                         (top - c[..., 1]) / (top - bottom) * height], axis=-1)


def auto_camera(scene: Scene, capture: Capture, elevation_deg: float = ELEVATION_DEG,
                azimuth_deg: float = AZIMUTH_DEG) -> ViewCamera:
    """The default camera: looks at the scene's centre from the relay wall's front side, raised by
    ``elevation_deg`` and turned by ``azimuth_deg`` away from the side where most of the scene lies.

    Args:
        capture: the resolved capture (:func:`datagen.scene.resolve_capture`): its FoV normal faces the
            sensor; ``fov_v`` is the wall's up direction, used as 'up' when the wall is horizontal (tal's
            z = 0 relay wall).
    Returns:
        :class:`ViewCamera` without an extent (see :func:`frame`).
    """
    n = np.asarray(capture.fov_normal, dtype=np.float64)
    z = np.array([0.0, 0.0, 1.0])
    up = z if abs(float(n @ z)) < 0.9 else safe_unit(np.asarray(capture.fov_v, dtype=np.float64))
    n_h = safe_unit(n - (n @ up) * up)
    s_h = safe_unit(np.cross(up, n_h))
    bounds = scene.bounds()
    centre = 0.5 * (bounds[0] + bounds[1])
    lateral = float((centre - capture.fov_center) @ s_h)
    side = 1.0 if lateral >= 0 else -1.0
    el, az = np.deg2rad(elevation_deg), np.deg2rad(azimuth_deg)
    back = np.cos(el) * (np.cos(az) * n_h - side * np.sin(az) * s_h) + np.sin(el) * up
    size = scene_size(scene)
    forward = -safe_unit(back)
    right = safe_unit(np.cross(forward, up))
    cam_up = np.cross(right, forward)
    eye = centre + back * 2.0 * size
    return ViewCamera(centre, eye, forward, right, cam_up, None, 0.01 * size, 4.0 * size)


def frame(camera: ViewCamera, points: np.ndarray, aspect: float, pad: float = FRAME_PAD) -> ViewCamera:
    """``camera`` with the extent that shows ``points`` (N, 3) m with ``pad`` margins at ``aspect`` = width /
    height (the shorter side is widened, so metres per pixel are the same both ways), and near / far clip
    distances 5 % of the depth span beyond the points."""
    c = camera.camera_coords(points)
    lo, hi = c[:, :2].min(axis=0), c[:, :2].max(axis=0)
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    half = np.maximum(half, MIN_SIZE) / (1 - 2 * pad)
    if half[0] / half[1] < aspect:
        half[0] = half[1] * aspect
    else:
        half[1] = half[0] / aspect
    depth_lo, depth_hi = float(c[:, 2].min()), float(c[:, 2].max())
    span = max(depth_hi - depth_lo, MIN_SIZE)
    near = max(depth_lo - 0.05 * span, 1e-4)
    return ViewCamera(camera.target, camera.eye, camera.forward, camera.right, camera.up,
                      (mid[0] - half[0], mid[0] + half[0], mid[1] - half[1], mid[1] + half[1]),
                      near, depth_hi + 0.05 * span)
