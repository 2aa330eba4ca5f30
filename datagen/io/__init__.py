"""I/O stage: simulation results on disk, and interoperability with y-tal (``tal``).

In: a :class:`~datagen.simulation.detection.Result` (``time_edges`` (T+1,) s, ``envelope`` channel_shape + (T,),
``components`` by name, int64 SPAD ``counts``, capture grids ``laser_points`` / ``sensor_points`` (…, 3) m,
``wall_normal`` (3,), attributes), a tal render YAML, or a tal HDF5 capture. Out: a Zarr v3 result store
(:func:`write_result`, :func:`read_result`, :func:`write_detection`), a datagen :class:`~datagen.scene.Scene`
with the :class:`TalCapture` saying how ``tal render`` would lay its result out (:func:`scene_from_tal_yaml`),
and tal's HDF5 capture files (:func:`write_tal_hdf5`, :func:`read_tal_hdf5`; H (T, Sx, Sy) or
(T, Lx, Ly, Sx, Sy) from :func:`tal_arrays`).

Exported here, what users call: :func:`write_result`, :func:`read_result`, :func:`write_detection`,
:func:`scene_from_tal_yaml`, :func:`tal_arrays`, :func:`write_tal_hdf5`, :func:`read_tal_hdf5`. Everything else
(:class:`~datagen.io.tal.TalCapture`, tal's enums ``HFormat`` / ``GridFormat`` / ``VolumeFormat`` in
:mod:`~datagen.io.tal_hdf5`, ...) is imported from its module.

Modules (they import each other directly, never through this package):

- :mod:`~datagen.io.store`: the Zarr result store (docs/physics.md §7);
- :mod:`~datagen.io.tal`: tal render YAML → scene and :class:`TalCapture` (frames, units, radiometry);
- :mod:`~datagen.io.tal_hdf5`: tal's HDF5 capture layout, a result as tal's fields, HDF5 read/write.
- :mod:`~datagen.io.lab_formats`: real labs' files both ways: Stanford LCT / f-k ``.mat`` (v5, v7.3) and
  ZNLOS HDF5 (docs/capture_io.md); :mod:`~datagen.io.lab_checks` checks their fields once read;
- :mod:`~datagen.io.orientation`: the one orientation of confocal scans (row up the wall, column to the right as
  the wall sees the hidden scene) and the LCT release's ``rect_data`` order and grid mapped to it, both ways;
- :mod:`~datagen.io.like_capture`: what a simulation of a stored capture must reproduce (grid, bins, time zero,
  detector) and its result put on the capture's bins (``simulate --like``).
"""
from .store import read_result, write_detection, write_result
from .tal import scene_from_tal_yaml
from .tal_hdf5 import read_tal_hdf5, tal_arrays, write_tal_hdf5

__all__ = [
    # result store
    "write_result", "read_result", "write_detection",
    # tal render YAML and HDF5 captures
    "scene_from_tal_yaml", "tal_arrays", "write_tal_hdf5", "read_tal_hdf5",
]
