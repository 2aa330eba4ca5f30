"""Moving hidden objects: an object's pose over time, and the frames of a capture sequence (docs/motion.md).

A moving object is built as any other (its builder's geometry is its pose "as built") and carries a ``motion``
block that gives, at every time t (seconds from the sequence's start), a rigid pose: the position of its
*anchor* (the centre of its axis-aligned bounding box as built) and a yaw (rotation about the vertical z axis
through the anchor, radians, 0 = as built). Three kinds, as the field's tracking papers move their targets:

- ``keyframes``: poses at given times, interpolated linearly (``smooth``: Catmull–Rom through the positions),
  held before the first and after the last;
- ``velocity``: constant speed from ``start`` (default: where it was built), turning at ``turn_rate_deg`` °/s
  (the velocity turns with the object: a circular arc);
- ``walk``: a walking person's path, waypoints on the floor (x, y) walked at ``speed`` m/s from ``start_time``,
  the object facing its direction of travel (as built it faces the first leg), standing still at the end or walking
  the path back and forth.

:class:`FrameSpec` (a capture's ``frames`` block) gives the sequence: ``count`` frames at ``rate`` Hz, each
exposed for ``exposure`` s from its start; a scanned capture visits its scan points one after another during the
exposure, point k (in ``scan_order``) at the middle of its dwell ``exposure / n_points``.
"""
from __future__ import annotations

import math
from typing import Annotated, Any, Literal, Union

import numpy as np
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, field_validator, model_validator

from ..units import parse_duration, parse_rate

Vec3 = tuple[float, float, float]

MAX_SPEED = 100.0
"""Fastest accepted motion, m/s (a car on a motorway is 40 m/s; a hidden room is metres across)."""

MAX_FRAMES = 100_000
"""Most frames a sequence may have (a minute at the fastest NLOS video rates of ~1 kHz)."""


def _seconds(value: Any) -> Any:
    return parse_duration(value) if isinstance(value, str) else value


def _hertz(value: Any) -> Any:
    return parse_rate(value) if isinstance(value, str) else value


Time = Annotated[float, BeforeValidator(_seconds), Field(ge=0, le=1e6)]
"""A time from the sequence's start: seconds, or a string such as "250ms"."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Keyframe(_Model):
    """One pose: at ``t`` s the anchor is at ``position`` (m) and the object turned by ``yaw_deg`` about z."""

    t: Time
    position: Vec3
    yaw_deg: float = 0.0


class KeyframeMotion(_Model):
    """Poses at keyframes (at least two, times increasing), interpolated; held outside their span."""

    kind: Literal["keyframes"]
    keyframes: list[Keyframe] = Field(min_length=2, max_length=10_000)
    interpolation: Literal["linear", "smooth"] = "linear"

    @field_validator("keyframes")
    @classmethod
    def _increasing(cls, frames: list[Keyframe]) -> list[Keyframe]:
        for i in range(1, len(frames)):
            if frames[i].t <= frames[i - 1].t:
                raise ValueError(f"keyframe times must increase: keyframes.{i}.t = {frames[i].t:g} s is not after "
                                 f"keyframes.{i - 1}.t = {frames[i - 1].t:g} s")
        return frames

    def pose(self, t: np.ndarray, anchor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        times = np.array([k.t for k in self.keyframes])
        pos = np.array([k.position for k in self.keyframes], dtype=np.float64)
        yaw = np.radians([k.yaw_deg for k in self.keyframes])
        tc = np.clip(t, times[0], times[-1])
        i = np.clip(np.searchsorted(times, tc, side="right") - 1, 0, len(times) - 2)
        s = ((tc - times[i]) / (times[i + 1] - times[i]))[:, None]
        if self.interpolation == "linear":
            p = pos[i] + s * (pos[i + 1] - pos[i])
        else:      # Catmull–Rom with end tangents from the one-sided differences
            prev, nxt = pos[np.maximum(i - 1, 0)], pos[np.minimum(i + 2, len(pos) - 1)]
            m0 = np.where((i > 0)[:, None], (pos[i + 1] - prev) / 2, pos[i + 1] - pos[i])
            m1 = np.where((i + 2 < len(pos))[:, None], (nxt - pos[i]) / 2, pos[i + 1] - pos[i])
            s2, s3 = s * s, s * s * s
            p = ((2 * s3 - 3 * s2 + 1) * pos[i] + (s3 - 2 * s2 + s) * m0 + (-2 * s3 + 3 * s2) * pos[i + 1]
                 + (s3 - s2) * m1)
        return p, yaw[i] + s[:, 0] * (yaw[i + 1] - yaw[i])


class VelocityMotion(_Model):
    """Constant speed ``velocity`` (m/s) from ``start`` (m; default: the anchor as built), turning about z at
    ``turn_rate_deg`` °/s with the velocity turning along: position p(t) = start + ∫₀ᵗ R(ωs) v ds."""

    kind: Literal["velocity"]
    velocity: Vec3
    turn_rate_deg: float = Field(0.0, ge=-3600, le=3600)
    start: Vec3 | None = None

    @field_validator("velocity")
    @classmethod
    def _speed(cls, v: Vec3) -> Vec3:
        if math.hypot(*v) > MAX_SPEED:
            raise ValueError(f"speed {math.hypot(*v):g} m/s is above {MAX_SPEED:g} m/s")
        return v

    def pose(self, t: np.ndarray, anchor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p0 = np.asarray(self.start if self.start is not None else anchor, dtype=np.float64)
        v = np.asarray(self.velocity, dtype=np.float64)
        w = math.radians(self.turn_rate_deg)
        if w == 0.0:
            return p0 + t[:, None] * v, np.zeros_like(t)
        s, c = np.sin(w * t), np.cos(w * t)     # ∫₀ᵗ R(ωs) ds = [[sin, −(1−cos)], [1−cos, sin]] / ω
        dx = (s * v[0] - (1 - c) * v[1]) / w
        dy = ((1 - c) * v[0] + s * v[1]) / w
        return p0 + np.stack([dx, dy, t * v[2]], axis=1), w * t


class WalkMotion(_Model):
    """A walk along ``path`` (waypoints (x, y) m on the floor; the anchor's height stays as built) at ``speed``
    m/s, starting at ``start_time`` s, facing the direction of travel; the object as built faces the first leg.
    At the path's end it stops (``at_end: stop``) or walks the path back and forth (``back_and_forth``)."""

    kind: Literal["walk"]
    path: list[tuple[float, float]] = Field(min_length=2, max_length=10_000)
    speed: float = Field(gt=0, le=MAX_SPEED)
    start_time: Time = 0.0
    at_end: Literal["stop", "back_and_forth"] = "stop"

    @field_validator("path")
    @classmethod
    def _legs(cls, path: list[tuple[float, float]]) -> list[tuple[float, float]]:
        for i in range(1, len(path)):
            if path[i] == path[i - 1]:
                raise ValueError(f"path.{i} repeats path.{i - 1} {list(path[i])}: every leg needs a length")
        return path

    def pose(self, t: np.ndarray, anchor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pts = np.asarray(self.path, dtype=np.float64)
        legs = np.diff(pts, axis=0)
        length = np.hypot(legs[:, 0], legs[:, 1])
        ends = np.concatenate([[0.0], np.cumsum(length)])
        walked = np.maximum((t - self.start_time) * self.speed, 0.0)
        back = np.zeros(len(t), dtype=bool)
        if self.at_end == "back_and_forth":
            walked = np.mod(walked, 2 * ends[-1])
            back = walked > ends[-1]
            walked = np.where(back, 2 * ends[-1] - walked, walked)
        d = np.minimum(walked, ends[-1])
        i = np.clip(np.searchsorted(ends, d, side="right") - 1, 0, len(legs) - 1)
        xy = pts[i] + ((d - ends[i]) / length[i])[:, None] * legs[i]
        heading = np.arctan2(legs[:, 1], legs[:, 0])
        pos = np.concatenate([xy, np.full((len(t), 1), anchor[2])], axis=1)
        return pos, heading[i] - heading[0] + np.where(back, np.pi, 0.0)


Motion = Annotated[Union[KeyframeMotion, VelocityMotion, WalkMotion], Field(discriminator="kind")]
"""An object's ``motion`` block in a scene file."""


def object_anchor(vertices: np.ndarray) -> np.ndarray:
    """(3,) float64: the centre of the axis-aligned bounding box of ``vertices`` (V, 3) m, the point a motion moves."""
    return 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))


def posed_vertices(motion: Any, vertices: np.ndarray, t: float | np.ndarray) -> np.ndarray:
    """``vertices`` (V, 3) m as built, moved to their pose at time ``t`` s by ``motion``: turned by the yaw about z
    through the anchor (:func:`object_anchor`), then the anchor moved to the position. A float ``t`` gives (V, 3)
    float64, times (n,) give (n, V, 3)."""
    anchor = object_anchor(vertices)
    times = np.atleast_1d(np.asarray(t, dtype=np.float64))
    pos, yaw = motion.pose(times, anchor)
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    rel = vertices - anchor
    out = np.empty((len(times),) + rel.shape)
    out[..., 0] = c * rel[:, 0] - s * rel[:, 1]
    out[..., 1] = s * rel[:, 0] + c * rel[:, 1]
    out[..., 2] = rel[:, 2]
    out += pos[:, None, :]
    return out[0] if np.ndim(t) == 0 else out


def velocity_at(motion: Any, vertices: np.ndarray, t: np.ndarray, dt: float = 1e-4) -> np.ndarray:
    """(n, 3) float64 m/s: the anchor's velocity at the times ``t`` (n,) s, a central difference over ±``dt``/2
    (one-sided at t = 0)."""
    anchor = object_anchor(vertices)
    t = np.asarray(t, dtype=np.float64)
    lo = np.maximum(t - dt / 2, 0.0)
    hi = lo + dt
    return (motion.pose(hi, anchor)[0] - motion.pose(lo, anchor)[0]) / dt


class FrameSpec(_Model):
    """A capture sequence: ``count`` frames at ``rate`` Hz from ``start`` s, each exposed for ``exposure`` s (at most
    a frame period); the detector draws each frame's histogram at that exposure (per scan point: the dwell
    ``exposure / n_points``). Scanned captures visit their points in ``scan_order`` ("raster": row by row;
    "serpentine": every other row reversed), point k at the middle of its dwell."""

    count: int = Field(ge=1, le=MAX_FRAMES)
    rate: Annotated[float, BeforeValidator(_hertz), Field(gt=0, le=1e9)]
    exposure: Annotated[float, BeforeValidator(_seconds), Field(gt=0)]
    start: Time = 0.0
    scan_order: Literal["raster", "serpentine"] = "raster"

    @model_validator(mode="after")
    def _fits(self) -> "FrameSpec":
        if self.exposure > 1.0 / self.rate * (1 + 1e-12):
            raise ValueError(f"exposure {self.exposure * 1e3:g} ms is longer than a frame (1/rate = "
                             f"{1e3 / self.rate:g} ms at {self.rate:g} Hz)")
        return self

    def times(self) -> np.ndarray:
        """(count,) float64 s: each frame's start."""
        return self.start + np.arange(self.count) / self.rate

    def point_times(self, n_points: int, shape: tuple[int, int] | None = None) -> np.ndarray:
        """(count, n_points) float64 s: when each scan point (in the capture's row-major order, rows of
        ``shape[1]`` points) is visited in each frame: the middle of its dwell, in ``scan_order``."""
        order = np.arange(n_points)
        if self.scan_order == "serpentine" and shape is not None:
            grid = order.reshape(shape).copy()
            grid[1::2] = grid[1::2, ::-1]
            order = np.argsort(grid.ravel())      # visit rank of each point
        dwell = self.exposure / n_points
        return self.times()[:, None] + (order[None, :] + 0.5) * dwell
