"""Plots: pictures of results (the top of the data flow beside analysis, datasets and I/O).

- :mod:`.envelope`: :func:`plot_envelope`, L(t) on a log scale with its components above the drawn SPAD
  histogram (the paper's Figure 7).
- :mod:`.energy` and :mod:`.figures`: the lookin estimator's sampling views (the paper's Figures 3 and 5):
  :func:`write_sampling_figures` (``datagen simulate --figures``).
- 3D pictures of scenes with open3d (``datagen view``): :mod:`.view_camera` (the orthographic
  :class:`ViewCamera`), :mod:`.view_geometry` (what is drawn: :func:`build_drawables`, class colours,
  cut-away, :func:`lookin_points`), :mod:`.view_worker` (open3d's import and checks, one render; run as a
  child process), :mod:`.view_render` (:func:`render_scene_image`: the child process with its watchdog),
  :mod:`.view_overlay` (legend, scale bar: :func:`render_scene`, :func:`scene_view_figure`). open3d is
  imported only inside the functions that render; without it they raise :class:`ViewUnavailable` (one line).

matplotlib is imported with the Agg backend; nothing here changes a result.

Exported here, what users call: :func:`plot_envelope`, :func:`write_sampling_figures`, :func:`render_scene`,
:func:`render_scene_image` and :class:`ViewUnavailable`; the rest is imported from its module.
- :mod:`.capture`: a measured capture beside its simulation (``compare-capture --png``); :mod:`.capture_maps`: the
  maps ``estimate-capture`` draws; :mod:`.zones`: a
  multi-zone capture's zone histograms; :mod:`.view_flood`: the flood and zones that ``datagen view`` adds;
  :mod:`.reconstruction`: a reconstruction's front view, depth map and top view (``datagen reconstruct``);
  :mod:`.sequence`: a capture sequence's tracks over the room's plan and its frames' changes (``datagen sequence``).
"""
from .envelope import plot_envelope
from .figures import write_sampling_figures
from .view_overlay import render_scene
from .view_render import render_scene_image
from .view_worker import ViewUnavailable

__all__ = ["plot_envelope", "write_sampling_figures", "render_scene", "render_scene_image", "ViewUnavailable"]
