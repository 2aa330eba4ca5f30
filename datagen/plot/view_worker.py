"""open3d access for the 3D pictures: the import and its system checks, and the render of one picture.

This module imports nothing from datagen (only the standard library, numpy and, inside functions, open3d),
so that :class:`datagen.plot.view_render.RenderWorker` can run it as a plain script in a child process
(``python view_worker.py READ_FD WRITE_FD``): the child then starts by importing open3d only, not datagen,
scipy and matplotlib (≈ 1.5 s less per picture).

open3d needs the Debian packages ``libusb-1.0-0`` (at import) and ``mesa-vulkan-drivers`` (a software Vulkan
driver, llvmpipe, for the offscreen renderer). Without a Vulkan driver open3d's renderer (Filament) aborts
the whole process, so :func:`require_open3d` checks for one first and raises :class:`ViewUnavailable` with a
one-line message naming what to install.
"""
from __future__ import annotations

import ctypes.util
import glob
import os
import sys

import numpy as np

INSTALL_HINT = ("pip install 'open3d==0.20.*' and, on Debian, apt-get install -y libusb-1.0-0 mesa-vulkan-drivers "
                "(bash scripts/test.sh does both as root)")
"""What to install for ``datagen view`` (the end of the one-line errors)."""

VULKAN_ICD_DIRS = ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d")
"""Where the Vulkan loader finds driver manifests (mesa-vulkan-drivers installs lvp_icd.*.json, a CPU driver)."""

BACKGROUND = (1.0, 1.0, 1.0)
"""Background colour of the 3D picture (RGB in [0, 1])."""


class ViewUnavailable(RuntimeError):
    """open3d or what its offscreen renderer needs is missing; the message is one line naming what to install."""


def vulkan_problem() -> str | None:
    """None when a Vulkan loader and at least one driver manifest exist, else what is missing (one line).

    Filament (open3d's renderer) aborts the whole process when it cannot create a Vulkan instance, so this is
    checked before a renderer is created."""
    if ctypes.util.find_library("vulkan") is None:
        return "no Vulkan loader (libvulkan.so.1)"
    listed = [p for var in ("VK_DRIVER_FILES", "VK_ICD_FILENAMES")
              for p in os.environ.get(var, "").split(os.pathsep) if p]
    if listed:
        return None if any(os.path.isfile(p) for p in listed) else "no Vulkan driver at VK_ICD_FILENAMES"
    if any(glob.glob(os.path.join(d, "*.json")) for d in VULKAN_ICD_DIRS):
        return None
    return "no Vulkan driver (no ICD manifest in /usr/share/vulkan/icd.d)"


def require_open3d(renderer: bool = True):
    """Import open3d and check that its offscreen renderer can run here.

    Args:
        renderer: also check for a Vulkan driver (not needed for ray casting or the interactive window).
    Returns:
        the ``open3d`` module (its own log output lowered to errors).
    Raises:
        ViewUnavailable: open3d is not installed, cannot be imported (e.g. libusb-1.0-0 missing), or no Vulkan
            driver is installed; the one-line message names what to install.
    """
    try:
        import open3d as o3d
    except ImportError as exc:
        detail = " ".join(str(exc).split())
        if "libusb" in detail:
            raise ViewUnavailable(f"open3d cannot be imported: {detail}: apt-get install -y libusb-1.0-0") from None
        raise ViewUnavailable(f"3D pictures need open3d, which is not installed ({detail}): {INSTALL_HINT}") from None
    except OSError as exc:   # a shared library it loads is missing
        raise ViewUnavailable(f"open3d cannot be imported ({' '.join(str(exc).split())}): {INSTALL_HINT}") from None
    if renderer:
        problem = vulkan_problem()
        if problem:
            raise ViewUnavailable(f"open3d's offscreen renderer needs Vulkan: {problem}: "
                                  "apt-get install -y mesa-vulkan-drivers")
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    return o3d


def triangle_mesh(o3d, vertices: np.ndarray, colors: np.ndarray):
    """open3d ``TriangleMesh`` of a triangle soup: ``vertices`` (3F, 3) float64 m, three per triangle, and
    per-vertex ``colors`` (3F, 3) float64 in [0, 1]."""
    V3 = o3d.utility.Vector3dVector
    mesh = o3d.geometry.TriangleMesh(V3(vertices), o3d.utility.Vector3iVector(np.arange(len(vertices)).reshape(-1, 3)))
    mesh.vertex_colors = V3(np.clip(colors, 0.0, 1.0))
    return mesh


def render_job(o3d, job: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render one picture with open3d's ``OffscreenRenderer`` (unlit shader, no post-processing: a pixel
    shows exactly the colour of the triangle it sees).

    Args:
        job: ``meshes`` list of (name, vertices (3F, 3) float64, colours (3F, 3)) triangle soups; ``size``
            (W, H) pixels; ``camera`` (target (3,), eye (3,), up (3,), (left, right, bottom, top) m,
            near m, far m) of an orthographic camera.
    Returns:
        (H, W, 3) uint8 RGB image, and the (4, 4) float64 view and projection matrices read back from
        open3d's camera after rendering (world → eye → clip).
    """
    R = o3d.visualization.rendering
    width, height = job["size"]
    target, eye, up, extent, near, far = job["camera"]
    renderer = R.OffscreenRenderer(width, height)
    renderer.scene.view.set_post_processing(False)      # no tone mapping: pixels are the colours
    renderer.scene.set_background([*BACKGROUND, 1.0])
    try:
        material = R.MaterialRecord()
        material.shader = "defaultUnlit"
        # every mesh stays referenced until the frame is rendered (freed ones made Filament stall)
        meshes = [triangle_mesh(o3d, vertices, colors) for _, vertices, colors in job["meshes"]]
        for k, ((name, _, _), mesh) in enumerate(zip(job["meshes"], meshes)):
            renderer.scene.add_geometry(f"{k}:{name}", mesh, material)
        camera = renderer.scene.camera
        camera.look_at(np.asarray(target).tolist(), np.asarray(eye).tolist(), np.asarray(up).tolist())
        camera.set_projection(R.Camera.Projection.Ortho, *extent, near, far)
        image = np.asarray(renderer.render_to_image())[:, :, :3].copy()
        view = np.asarray(camera.get_view_matrix(), dtype=np.float64).copy()
        projection = np.asarray(camera.get_projection_matrix(), dtype=np.float64).copy()
    finally:
        renderer.scene.clear_geometry()      # Filament panics if a renderer dies with geometry in it
    return image, view, projection


def worker_main(read_fd: int, write_fd: int) -> None:
    """The child process: import open3d, report ready, render the one job read from ``read_fd`` and send the
    answer on ``write_fd``, then leave at once (``os._exit``: no Filament teardown).

    Answers: ("unavailable", message), ("ready", None), ("ok", (image, view, projection)) or ("error",
    one-line message)."""
    from multiprocessing.connection import Connection

    jobs, answers = Connection(read_fd, writable=False), Connection(write_fd, readable=False)
    try:
        o3d = require_open3d()
    except ViewUnavailable as exc:
        answers.send(("unavailable", str(exc)))
        os._exit(0)
    answers.send(("ready", None))
    try:
        job = jobs.recv()
    except EOFError:
        job = None
    if job is not None:
        try:
            answers.send(("ok", render_job(o3d, job)))
        except Exception as exc:  # noqa: BLE001 - reported to the parent as one line
            answers.send(("error", f"{type(exc).__name__}: {' '.join(str(exc).split())}"))
    os._exit(0)


if __name__ == "__main__":
    worker_main(int(sys.argv[1]), int(sys.argv[2]))
