"""Render a scene's :class:`~datagen.plot.view_geometry.Drawables` offscreen with open3d, in a child process
with a watchdog; and open open3d's interactive window.

Every picture is rendered by a fresh child process (:class:`RenderWorker`) running
:mod:`datagen.plot.view_worker` as a script, with a watchdog. Why: open3d 0.20's renderer (Filament on
llvmpipe's Vulkan driver) sometimes stalls a frame for tens of seconds to minutes with the cores spinning.
Measured on the 2-core machine with the demo room at 2100×1720 (1050×860 supersampled) while other jobs
loaded it (load average 6-9): in one process, a second ``OffscreenRenderer`` after a first one hung in 3 of 3
tries (killed after 118-198 s), and frames of one reused renderer took 38-50 s; with a fresh child per
picture, 20 pictures took 21 attempts: one stalled (killed after 30 s, the retry rendered), the others
rendered in 1.4-2.5 s (median 1.8 s) after a 1.3-1.9 s child start. A child that has not answered within
:data:`RENDER_TIMEOUT_S` (doubled at each retry) is killed and the picture retried in a new one. The child
also keeps Filament's abort, when no Vulkan instance can be created, out of the caller (reported as
:class:`~datagen.plot.view_worker.ViewUnavailable`). Every mesh must stay referenced until the frame is
rendered: meshes freed after ``add_geometry`` made every frame stall (:func:`~datagen.plot.view_worker.render_job`).

Lines and points are drawn as camera-facing triangles (:func:`ribbons`, :func:`discs`): open3d's Vulkan
renderer draws every line 1 pixel wide whatever its ``line_width``. Rendering uses the unlit shader and no
post-processing, so a pixel shows exactly the colour of the triangle it sees (tests/test_view.py checks the
colour at the projection of a box's centre through the renderer's camera).
"""
from __future__ import annotations

import atexit
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection

import numpy as np

from ..scene import Scene
from . import view_worker
from .view_camera import ViewCamera, safe_unit
from .view_geometry import Drawables, build_drawables
from .view_worker import ViewUnavailable, require_open3d

RENDER_TIMEOUT_S = 15.0
"""A picture not rendered after this long is abandoned and retried in a fresh child, with twice the time at
each retry (15, 30, 60, 120 s: a slow machine still gets there). A 1050×860 picture rendered in 1.4-2.5 s on
the loaded 2-core machine; Filament's stalls last tens of seconds to minutes (module doc)."""

RENDER_ATTEMPTS = 4
"""Renders tried (each in a fresh child after a stall) before giving up."""

WORKER_START_TIMEOUT_S = 120.0
"""Time allowed for a new child to import open3d and report ready (slow on a loaded machine)."""

SUPERSAMPLE = 2
"""The 3D picture is rendered this many times larger and averaged down (anti-aliased edges and lines)."""


class RenderWorker:
    """Renders each picture in a fresh child process, killed if it stalls (see the module doc).

    The child is a plain ``python -P view_worker.py READ_FD WRITE_FD`` subprocess talking over two pipes: it
    imports open3d but not datagen, and callers need no ``if __name__ == "__main__"`` guard."""

    def __init__(self):
        self.proc = None
        self.jobs = self.answers = self.log = None
        self.attempts: list[tuple[float, float, str]] = []
        """The last :meth:`render`'s attempts: (start s, render s, "ok" | "error" | "timeout") each."""

    def _start(self) -> None:
        parent_read, child_write = os.pipe()
        child_read, parent_write = os.pipe()
        self.log = tempfile.TemporaryFile()
        # -P: the script's folder (datagen/plot) is not put on sys.path; stdout (Filament's banner) is dropped
        self.proc = subprocess.Popen([sys.executable, "-P", view_worker.__file__, str(child_read), str(child_write)],
                                     pass_fds=(child_read, child_write), stdin=subprocess.DEVNULL,
                                     stdout=subprocess.DEVNULL, stderr=self.log)
        os.close(child_read)
        os.close(child_write)
        self.jobs = Connection(parent_write, readable=False)
        self.answers = Connection(parent_read, writable=False)
        status, payload = self._receive(WORKER_START_TIMEOUT_S, "start")
        if status == "unavailable":
            self.stop()
            raise ViewUnavailable(payload)
        if status == "timeout":
            self.stop()
            raise RuntimeError(f"open3d's renderer process did not start within {WORKER_START_TIMEOUT_S:g} s")

    def _receive(self, timeout: float, what: str):
        if not self.answers.poll(timeout):
            return "timeout", None
        try:
            return self.answers.recv()
        except EOFError:
            self.proc.wait(5.0)
            code = self.proc.returncode
            self.log.seek(0)
            tail = " ".join(self.log.read().decode(errors="replace").split())[-240:]
            self.stop()
            hint = ("; is a Vulkan driver installed? apt-get install -y mesa-vulkan-drivers"
                    if code is not None and code < 0 else "")
            raise ViewUnavailable(f"open3d's renderer process died during {what} (exit code {code}"
                                  f"{': ' + tail if tail else ''}){hint}") from None

    def render(self, job: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Render ``job`` (:func:`datagen.plot.view_worker.render_job`) in a fresh child (a new one after a stall).

        Returns:
            (H, W, 3) uint8 image, (4, 4) view and projection matrices.
        Raises:
            ViewUnavailable: the child cannot render (open3d or Vulkan missing, or it died).
            RuntimeError: open3d raised, or every attempt stalled.
        """
        self.attempts = []
        for attempt in range(RENDER_ATTEMPTS):
            t0 = time.perf_counter()
            self._start()
            t1 = time.perf_counter()
            self.jobs.send(job)
            status, payload = self._receive(RENDER_TIMEOUT_S * 2 ** attempt, "rendering")
            self.stop()                                   # done, failed or stalled: this child is finished
            self.attempts.append((t1 - t0, time.perf_counter() - t1, status))
            if status == "ok":
                return payload
            if status == "error":
                raise RuntimeError(f"open3d's renderer failed: {payload}")
        waited = ", ".join(f"{RENDER_TIMEOUT_S * 2 ** k:g}" for k in range(RENDER_ATTEMPTS))
        raise RuntimeError(f"open3d's offscreen renderer stalled {RENDER_ATTEMPTS} times (killed after {waited} s); "
                           "is the CPU overloaded?")

    def stop(self) -> None:
        """End the child (asked to stop, killed if it does not within 2 s)."""
        proc, jobs, answers, log = self.proc, self.jobs, self.answers, self.log
        self.proc = self.jobs = self.answers = self.log = None
        if proc is None:
            return
        try:
            jobs.send(None)
        except (OSError, ValueError):
            pass
        try:
            proc.wait(2.0)
        except subprocess.TimeoutExpired:                 # stuck in a frame
            proc.kill()
            proc.wait(5.0)
        for c in (jobs, answers, log):
            c.close()


WORKER = RenderWorker()
"""The renderer used by :func:`render_scene_image` (its child is stopped at exit)."""
atexit.register(WORKER.stop)


@dataclass
class SceneImage:
    """A rendered 3D picture (no legend) and the camera that made it.

    Attributes:
        image: (H, W, 3) uint8 RGB.
        view_matrix, projection_matrix: (4, 4) float64, open3d's camera (world → eye → clip), read back from
            the renderer after rendering.
        camera: the :class:`~datagen.plot.view_camera.ViewCamera`; drawables: what was drawn (legend,
            cut-away surfaces).
        seconds: wall time of the renderer (child start, set-up and rendering), s.
    """

    image: np.ndarray
    view_matrix: np.ndarray
    projection_matrix: np.ndarray
    camera: ViewCamera
    drawables: Drawables
    seconds: float

    def project(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) world points (m) → (..., 2) float64 pixel coordinates (column, row) of :attr:`image`,
        through the renderer's own view and projection matrices (pixel centres at +0.5)."""
        p = np.asarray(points, dtype=np.float64)
        h = np.concatenate([p, np.ones(p.shape[:-1] + (1,))], axis=-1) @ (self.projection_matrix @ self.view_matrix).T
        ndc = h[..., :3] / h[..., 3:4]
        height, width = self.image.shape[:2]
        return np.stack([(ndc[..., 0] + 1) / 2 * width, (1 - ndc[..., 1]) / 2 * height], axis=-1)


def _double_sided(tri: np.ndarray, color) -> tuple[np.ndarray, np.ndarray]:
    """(T·3, 3) triangle corners → both windings (2T·3, 3) and their colours (2T·3, 3)."""
    both = np.concatenate([tri, tri.reshape(-1, 3, 3)[:, ::-1].reshape(-1, 3)])
    return both, np.tile(np.asarray(color, dtype=np.float64), (len(both), 1))


def ribbons(lines: list, camera: ViewCamera, mpp: float) -> list:
    """:attr:`Drawables.lines` as camera-facing ribbons of their width (output pixels × ``mpp`` metres per
    pixel) with square caps, as mesh tuples like :attr:`Drawables.meshes` (both windings)."""
    out = []
    for name, seg, color, width in lines:
        if len(seg) == 0:
            continue
        a, b = seg[:, 0], seg[:, 1]
        side = np.cross(b - a, camera.forward)
        length = np.linalg.norm(side, axis=1)
        ok = length > 1e-12 * max(1.0, float(np.abs(seg).max()))   # segments seen end-on vanish
        if not ok.any():
            continue
        a, b, side, length = a[ok], b[ok], side[ok], length[ok]
        half = side / length[:, None] * (0.5 * width * mpp)
        ext = safe_unit(b - a) * (0.5 * width * mpp)                 # square caps: corners meet
        q = np.stack([a - ext - half, b + ext - half, b + ext + half, a - ext + half], axis=1)   # (E, 4, 3)
        out.append((name, *_double_sided(q[:, [0, 1, 2, 0, 2, 3]].reshape(-1, 3), color)))
    return out


def discs(points: list, camera: ViewCamera, mpp: float, sides: int = 8) -> list:
    """:attr:`Drawables.points` as camera-facing discs of their diameter (output pixels × ``mpp``), as mesh
    tuples (both windings)."""
    out = []
    ang = 2 * np.pi * np.arange(sides) / sides
    ring = np.cos(ang)[:, None] * camera.right + np.sin(ang)[:, None] * camera.up          # (S, 3)
    j = np.arange(sides)
    for name, pts, color, size in points:
        if len(pts) == 0:
            continue
        rim = pts[:, None, :] + 0.5 * size * mpp * ring                                      # (N, S, 3)
        tri = np.stack([np.broadcast_to(pts[:, None, :], rim.shape), rim, rim[:, (j + 1) % sides]], axis=2)
        out.append((name, *_double_sided(tri.reshape(-1, 3), color)))
    return out


def render_scene_image(scene: Scene, width: int = 960, height: int = 640, *, lookins: np.ndarray | None = None,
                       shading: str = "shaded", edges: bool = True, supersample: int = SUPERSAMPLE,
                       camera: ViewCamera | None = None, cut_away: bool = True,
                       extra: Drawables | None = None) -> SceneImage:
    """Render ``scene`` offscreen with open3d: the 3D picture only (no legend; see
    :func:`datagen.plot.view_overlay.render_scene`).

    Args:
        width, height: picture size in pixels (at least 16).
        lookins: (N, 3) m lookin hit points to overlay (:func:`~datagen.plot.view_geometry.lookin_points`).
        shading: "shaded" or "flat" (every pixel of an object exactly its class colour).
        edges: draw object outlines.
        supersample: render this many times larger and average down (1: no anti-aliasing, exact colours).
        camera: camera (default :func:`~datagen.plot.view_camera.auto_camera`), framed to the scene.
        cut_away: cut away walls and ceiling in front of the scene.
        extra: more lines and legend entries (:func:`~datagen.plot.view_geometry.build_drawables`).
    Returns:
        :class:`SceneImage`.
    Raises:
        ViewUnavailable: open3d or a Vulkan driver is missing.
        SceneError: the scene's capture cannot be resolved.
        ValueError: a picture smaller than 16×16, supersample < 1 or an unknown shading.
        RuntimeError: the renderer failed or kept stalling.
    """
    if width < 16 or height < 16 or supersample < 1:
        raise ValueError(f"picture size must be at least 16×16 and supersample >= 1, got {width}×{height}, "
                         f"supersample {supersample}")
    o3d = require_open3d()
    d = build_drawables(o3d, scene, lookins=lookins, shading=shading, edges=edges, camera=camera,
                        aspect=width / height, cut_away=cut_away, extra=extra)
    cam = d.camera
    mpp = cam.metres_per_pixel(width)
    job = {"meshes": d.meshes + ribbons(d.lines, cam, mpp) + discs(d.points, cam, mpp),
           "size": (width * supersample, height * supersample),
           "camera": (cam.target, cam.eye, cam.up, cam.extent, cam.near, cam.far)}
    t0 = time.perf_counter()
    img, view, proj = WORKER.render(job)
    seconds = time.perf_counter() - t0
    if supersample > 1:
        img = img[:, :, :3].reshape(height, supersample, width, supersample, 3).mean(axis=(1, 3))
        img = np.round(img).astype(np.uint8)
    return SceneImage(img[:, :, :3], view, proj, cam, d, seconds)


def require_display() -> None:
    """Raise :class:`ViewUnavailable` (one line) when neither ``DISPLAY`` nor ``WAYLAND_DISPLAY`` is set."""
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise ViewUnavailable("--show needs a display (neither DISPLAY nor WAYLAND_DISPLAY is set); "
                              "write a PNG with --out instead")


def show_drawables(d: Drawables, title: str = "datagen view") -> None:
    """Open open3d's interactive window on ``d`` (blocks until it is closed; lines 1 pixel wide).

    Raises:
        ViewUnavailable: no display, or open3d missing.
    """
    require_display()
    o3d = require_open3d(renderer=False)
    V3 = o3d.utility.Vector3dVector
    geoms = [view_worker.triangle_mesh(o3d, verts, cols) for _, verts, cols in d.meshes]
    for _, seg, color, _ in d.lines:
        if len(seg):
            ls = o3d.geometry.LineSet(V3(seg.reshape(-1, 3)),
                                      o3d.utility.Vector2iVector(np.arange(2 * len(seg)).reshape(-1, 2)))
            ls.colors = V3(np.tile(np.asarray(color, dtype=np.float64), (len(seg), 1)))
            geoms.append(ls)
    for _, pts, color, _ in d.points:
        pc = o3d.geometry.PointCloud(V3(pts))
        pc.colors = V3(np.tile(np.asarray(color, dtype=np.float64), (len(pts), 1)))
        geoms.append(pc)
    o3d.visualization.draw_geometries(geoms, window_name=title, width=1280, height=800,
                                      lookat=d.camera.target, front=-d.camera.forward, up=d.camera.up, zoom=0.7)
