"""A binary mask at a depth as a planar cut-out (datagen.scene.builders.mask_mesh, the scene files' ``mask``
builder): its area, where it lies, which way it faces, and that a ray caster sees exactly its filled cells."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from datagen.scene import scene_from_dict
from datagen.scene.parts import SceneError
from datagen.scene.builders import mask_cutout, mask_mesh


def f_mask() -> np.ndarray:
    """An asymmetric 5 × 4 "F" (row 0 lowest): the stem in column 0, bars at rows 4 and 2."""
    m = np.zeros((5, 4), bool)
    m[:, 0] = True
    m[4, :] = True
    m[2, :2] = True
    return m


def test_area_position_and_facing():
    mask, pitch, center = f_mask(), 0.01, np.array([0.3, 0.4, -0.2])
    v, f = mask_mesh(mask, pitch, center, u=(1, 0, 0), v=(0, 0, 1))
    mesh = trimesh.Trimesh(v, f, process=False)
    assert mesh.area == pytest.approx(mask.sum() * pitch ** 2, rel=1e-12)
    np.testing.assert_allclose(v[:, 1], 0.4)                           # planar, at the centre's depth
    np.testing.assert_allclose(mesh.face_normals, np.tile([0.0, -1.0, 0.0], (len(f), 1)), atol=1e-12)  # u × v
    # the extent: 4 columns and 5 rows of 1 cm about the centre
    np.testing.assert_allclose(v.min(0)[[0, 2]], center[[0, 2]] - [0.02, 0.025])
    np.testing.assert_allclose(v.max(0)[[0, 2]], center[[0, 2]] + [0.02, 0.025])
    assert len(f) == 2 * int((np.diff(np.pad(mask.astype(int), ((0, 0), (1, 0))), axis=1) == 1).sum())


def test_rows_grow_up_and_columns_along_u():
    """Cell (iy, ix)'s centre sits ix pitches along u and iy up v from the lower-left cell's: the mesh covers the
    filled cells' centres and none of the empty ones'."""
    mask, pitch = f_mask(), 0.02
    v, f = mask_mesh(mask, pitch, (0.0, 0.5, 0.0), u=(1, 0, 0), v=(0, 0, 1))
    tris = v[f][:, :, [0, 2]]                                  # the plane y = 0.5 as (u, v)
    iy, ix = np.meshgrid(np.arange(5), np.arange(4), indexing="ij")
    centres = np.stack([(ix - 1.5) * pitch, (iy - 2) * pitch], -1).reshape(-1, 2)
    edge = np.roll(tris, -1, axis=1) - tris                    # (F, 3, 2)
    rel = centres[:, None, None, :] - tris[None]               # (P, F, 3, 2)
    cross = edge[None, ..., 0] * rel[..., 1] - edge[None, ..., 1] * rel[..., 0]
    inside = ((cross >= 0).all(-1) | (cross <= 0).all(-1)).any(-1)
    np.testing.assert_array_equal(inside.reshape(mask.shape), mask)


def test_tilted_frame():
    """u and v need only be perpendicular: a cut-out tilted 30° about z keeps its area and lies in its plane."""
    a = np.deg2rad(30)
    u, v = (np.cos(a), np.sin(a), 0.0), (0.0, 0.0, 2.0)
    verts, faces = mask_mesh(np.ones((3, 3), bool), 0.1, (1.0, 1.0, 1.0), u, v)
    mesh = trimesh.Trimesh(verts, faces, process=False)
    assert mesh.area == pytest.approx(0.09)
    normal = np.cross(u, np.asarray(v) / 2)
    np.testing.assert_allclose((verts - [1.0, 1.0, 1.0]) @ normal, 0.0, atol=1e-12)


def test_text_rows_are_a_picture_top_row_first():
    obj = mask_cutout("f", ["####", "#...", "##..", "#...", "#..."], 0.01, (0.0, 0.4, 0.0))
    ref, _ = mask_mesh(f_mask(), 0.01, (0.0, 0.4, 0.0))
    assert sorted(map(tuple, np.round(obj.vertices, 12))) == sorted(map(tuple, np.round(ref, 12)))


@pytest.mark.parametrize("args, text", [
    (dict(rows=["##", "#"]), "equally long"),
    (dict(rows=["#x"]), "rows.0 column 1: 'x'"),
    (dict(rows=[".."]), "none of its 1 x 2 cells is filled"),
    (dict(rows=["#"], pitch=0.0), "pitch must be > 0"),
    (dict(rows=["#"], v=(1.0, 0.0, 0.0)), "must be perpendicular"),
])
def test_bad_masks_say_what_in_one_line(args, text):
    kwargs = {"name": "cut", "rows": ["#"], "pitch": 0.01, "center": (0.0, 0.5, 0.0), **args}
    with pytest.raises(SceneError, match="mask 'cut'") as exc:
        mask_cutout(**kwargs)
    assert text in str(exc.value) and "\n" not in str(exc.value)


def test_scene_file_mask_builder():
    data = {"objects": [{"builder": "quad", "name": "relay_wall", "label": "relay_wall", "corner": [-1, 0, -1],
                         "edge_u": [2, 0, 0], "edge_v": [0, 0, 2]},
                        {"builder": "mask", "name": "dot", "rows": [".#.", "###", ".#."], "pitch": 0.02,
                         "center": [0.0, 0.4, 0.0], "material": {"kind": "retroreflective", "albedo": 0.9}}],
            "laser": {"emitter": [0, 2, 0], "spot": [0, 0, 0]},
            "sensor": {"position": [0, 2, 0], "fov": {"center": [0, 0, 0], "size": [0.1, 0.1]}}}
    scene = scene_from_dict(data, "chart.yaml")
    dot = scene.objects[1]
    assert trimesh.Trimesh(dot.vertices, dot.faces).area == pytest.approx(5 * 0.02 ** 2)
    data["objects"][1]["rows"] = ["#?"]
    with pytest.raises(SceneError, match=r"chart.yaml: objects.1: mask 'dot': rows.0 column 1: '\?'"):
        scene_from_dict(data, "chart.yaml")
