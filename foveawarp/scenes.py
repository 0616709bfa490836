"""Built-in procedural scenes, generated deterministically in code at load time (no downloads).

- ``cornell``: the classic box, two blocks, a spot light from the ceiling (indirect light, DoF, bleeding).
- ``city``: a seeded voxel city of more than 1M triangles (the large-scene performance case).
- ``eyechart``: walls of high-contrast gratings and letters at many spatial frequencies and distances.
- ``earth``: a low-poly sphere (960 triangles) with a procedural albedo.
- ``bunny-in-box``: the Cornell box with the Stanford bunny (shipped in ``assets/``) inside.
- ``room``: a textured room (brick wall, wooden floor, a framed picture, a metallic sphere and rough plastic
  objects), open on one side to a sky; its textures are made in NumPy at load time.

Named textured scenes read from files (:func:`file_scene`): ``suzanne``, ``wicker`` (shipped in
``assets/gltf-models/``), ``barrel``, ``milk-truck`` (glTF models in the shared scenes folder,
``$FOVEAWARP_SCENES_DIR``), each framed by a camera that orbits it, and ``grey-white-room`` (the Mitsuba scene,
with ``foveawarp.io.mitsuba``).

Importing this module registers ``BUILTIN``, :func:`mesh_on_ground` and :func:`file_scene` with
:func:`foveawarp.scene.load_scene` (``scene`` never imports this module).
"""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path
from typing import Optional

import numpy as np

from .camera import Camera
from .config import check_array, check_bool, check_finite, check_int_range, check_range, check_vec, show
from .materials import Material, MaterialTable, TextureRef, default_material
from .meshio import (TEXTURED_SCENES, find_named_mesh, find_textured_scene, load_mesh_arrays, load_mesh_parts,
                     named_mesh_help, textured_scene_help)
from .scene import AreaLight, Light, Scene, SceneObject, check_bvh, face_material_colors, register_builtin_scenes

__all__ = ["SceneBuilder", "cornell", "city", "eyechart", "earth", "bunny_in_box", "room", "mesh_on_ground",
           "file_scene", "scene_from_data", "lights_from_file", "default_lights", "vertex_tangents", "with_materials",
           "BUILTIN"]


def rot_y(angle_rad: float) -> np.ndarray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], dtype=np.float64)


def translation(t) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = t
    return m


class SceneBuilder:
    """Accumulates triangle groups with materials, then builds a :class:`Scene`.

    Textured content: :meth:`add_image` adds a linear image and returns its index for ``TextureRef.image``;
    ``add_mesh(..., uvs=..., material=...)`` gives a mesh UVs and a :class:`foveawarp.materials.Material`. Once a
    mesh has a material the built scene has materials for every face (a mesh without one gets a rough dielectric
    of its constant ``albedo``), UVs (0 where a mesh has none) and tangents (:func:`vertex_tangents`); the
    ``face_albedo`` of a mesh with a material is its mean base colour. Without any material the scene is built
    as it always was."""

    def __init__(self):
        self.v, self.f, self.alb, self.emi, self.vn, self.smooth = [], [], [], [], [], []
        self.uv, self.mat = [], []
        self.materials, self.images = [], []
        self.objects = []
        self.nv = 0

    def add_image(self, image) -> int:
        """Add a linear (H, W, C) image (C in 1..4, finite); returns its index."""
        a = check_array(f"images[{len(self.images)}]", image)
        if a.ndim != 3 or a.shape[2] not in (1, 2, 3, 4):
            raise ValueError(f"images[{len(self.images)}] must be an (H, W, 1..4) array, got shape {a.shape}")
        self.images.append(np.ascontiguousarray(a, dtype=np.float32))
        return len(self.images) - 1

    def _material_index(self, material) -> int:
        for i, m in enumerate(self.materials):
            if m is material or m == material:
                return i
        self.materials.append(material)
        return len(self.materials) - 1

    def add_mesh(self, vertices, faces, albedo, emission=(0.0, 0.0, 0.0), normals=None, smooth=False,
                 name=None, motion=None, uvs=None, material=None):
        """Add triangles: ``vertices`` (V, 3) finite, ``faces`` (F, 3) integers in [0, V - 1], ``albedo`` (3,) or
        (F, 3) in [0, 1], ``emission`` (3,) >= 0, ``normals`` None or (V, 3), ``smooth`` bool, ``name`` None or
        str, ``motion`` None or a callable ``t -> 4x4``, ``uvs`` None or (V, 2) finite (glTF convention, v
        down), ``material`` None or a :class:`foveawarp.materials.Material` (its base colour then replaces
        ``albedo``, which may be None)."""
        if material is not None and not isinstance(material, Material):
            raise ValueError(f"material must be None or a foveawarp.materials.Material, got {show(material)}")
        if albedo is None:
            if material is None:
                raise ValueError("albedo must be (3,) or (F, 3) linear RGB in [0, 1], got None (allowed only with a "
                                 "material)")
            albedo = material.base_color_factor[:3]
        vertices = check_array("vertices", vertices).astype(np.float64)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or vertices.shape[0] < 3:
            raise ValueError(f"vertices must have shape (V >= 3, 3), got {vertices.shape}")
        faces = check_array("faces", faces, lo=0, hi=vertices.shape[0] - 1)
        if faces.ndim != 2 or faces.shape[1] != 3 or faces.shape[0] < 1 or faces.dtype.kind not in "iu":
            raise ValueError(f"faces must be an (F >= 1, 3) integer array of triangle vertex indices, got shape "
                             f"{faces.shape} of {faces.dtype}")
        faces = faces.astype(np.int64)
        nf = faces.shape[0]
        albedo = check_array("albedo", albedo, lo=0.0, hi=1.0).astype(np.float32)
        if albedo.shape == (3,):
            albedo = np.broadcast_to(albedo, (nf, 3))
        if albedo.shape != (nf, 3):
            raise ValueError(f"albedo must have shape (3,) or ({nf}, 3), got {albedo.shape}")
        emission = check_vec("emission", emission, 3, 0.0)
        if normals is not None:  # non-finite normals (degenerate faces of loaded meshes) become 0, as in Scene
            normals = np.asarray(normals)
            if normals.dtype.kind not in "biuf":
                raise ValueError(f"normals must be an array of real numbers, got dtype {normals.dtype}")
            normals = np.nan_to_num(normals.astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)
            if normals.shape != vertices.shape:
                raise ValueError(f"normals must have the shape of vertices {vertices.shape}, got {normals.shape}")
        smooth = check_bool("smooth", smooth)
        if uvs is not None:
            uvs = check_array("uvs", uvs).astype(np.float64)
            if uvs.shape != (vertices.shape[0], 2):
                raise ValueError(f"uvs must have shape ({vertices.shape[0]}, 2), got {uvs.shape}")
        if name is not None and not isinstance(name, str):
            raise ValueError(f"name must be None or a str, got {show(name)}")
        if motion is not None and not callable(motion):
            raise ValueError(f"motion must be None or a callable t -> 4x4 matrix, got {show(motion)}")
        start = self.nv
        self.v.append(vertices)
        self.f.append(faces + start)
        self.alb.append(albedo)
        self.emi.append(np.broadcast_to(np.asarray(emission, dtype=np.float32), (nf, 3)))
        if normals is None:
            normals = np.zeros_like(vertices)
        self.vn.append(np.asarray(normals, dtype=np.float64))
        self.smooth.append(np.full(nf, 1 if smooth else 0, dtype=np.uint8))
        self.uv.append(uvs)
        self.mat.append((material, nf))
        self.nv += vertices.shape[0]
        if name is not None or motion is not None:
            self.objects.append(SceneObject(name or f"object{len(self.objects)}", (start, self.nv), motion))
        return start, self.nv

    def add_quad(self, corner, edge_u, edge_v, albedo, emission=(0.0, 0.0, 0.0), **kw):
        c, u, w = (np.asarray(check_vec(n, a), dtype=np.float64) for n, a in
                   (("corner", corner), ("edge_u", edge_u), ("edge_v", edge_v)))
        verts = np.stack([c, c + u, c + u + w, c + w])
        return self.add_mesh(verts, [[0, 1, 2], [0, 2, 3]], albedo, emission, **kw)

    def add_box(self, center, size, albedo, yaw_rad=0.0, **kw):
        """Axis box (rotated about y by ``yaw_rad``) with outward-facing triangles; ``size`` (3,) >= 0."""
        hs = np.asarray(check_vec("size", size, 3, 0.0), dtype=np.float64) * 0.5
        center = check_vec("center", center)
        corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64) * hs
        corners = corners @ rot_y(check_finite("yaw_rad", yaw_rad)).T + np.asarray(center, dtype=np.float64)
        # indices: bit2 = x, bit1 = y, bit0 = z
        faces = [
            [0, 1, 3], [0, 3, 2],  # -x
            [4, 6, 7], [4, 7, 5],  # +x
            [0, 4, 5], [0, 5, 1],  # -y
            [2, 3, 7], [2, 7, 6],  # +y
            [0, 2, 6], [0, 6, 4],  # -z
            [1, 5, 7], [1, 7, 3],  # +z
        ]
        return self.add_mesh(corners, faces, albedo, **kw)

    def add_sphere(self, center, radius, n_lon=24, n_lat=21, albedo=(0.8, 0.8, 0.8), albedo_fn=None, smooth=True,
                   **kw):
        """UV sphere: ``n_lon * 2 * (n_lat - 2) + 2 * n_lon`` triangles (960 for 24 x 21); ``radius`` > 0,
        ``n_lon`` in [3, 4096], ``n_lat`` in [2, 4096]."""
        center = check_vec("center", center)
        radius = check_range("radius", radius, 0.0, None, lo_open=True)
        n_lon = check_int_range("n_lon", n_lon, 3, 4096)
        n_lat = check_int_range("n_lat", n_lat, 2, 4096)
        if albedo_fn is not None and not callable(albedo_fn):
            raise ValueError(f"albedo_fn must be None or a callable centroids -> (F, 3) albedo, got {show(albedo_fn)}")
        verts = [[0.0, 1.0, 0.0]]
        for i in range(1, n_lat):
            th = math.pi * i / n_lat
            for j in range(n_lon):
                ph = 2.0 * math.pi * j / n_lon
                verts.append([math.sin(th) * math.cos(ph), math.cos(th), math.sin(th) * math.sin(ph)])
        verts.append([0.0, -1.0, 0.0])
        verts = np.asarray(verts)
        faces = []
        for j in range(n_lon):
            faces.append([0, 1 + (j + 1) % n_lon, 1 + j])
        for i in range(n_lat - 2):
            r0, r1 = 1 + i * n_lon, 1 + (i + 1) * n_lon
            for j in range(n_lon):
                j1 = (j + 1) % n_lon
                faces.append([r0 + j, r0 + j1, r1 + j1])
                faces.append([r0 + j, r1 + j1, r1 + j])
        last = len(verts) - 1
        r0 = 1 + (n_lat - 2) * n_lon
        for j in range(n_lon):
            faces.append([last, r0 + j, r0 + (j + 1) % n_lon])
        faces = np.asarray(faces)
        if albedo_fn is not None:
            albedo = albedo_fn(verts[faces].mean(axis=1))
        return self.add_mesh(verts * radius + np.asarray(center), faces, albedo, normals=verts, smooth=smooth, **kw)

    def build(self, **kw) -> Scene:
        if all(m is None for m, _ in self.mat):
            return Scene(
                vertices=np.concatenate(self.v).astype(np.float32),
                faces=np.concatenate(self.f).astype(np.int32),
                face_albedo=np.concatenate(self.alb).astype(np.float32),
                face_emission=np.concatenate(self.emi).astype(np.float32),
                vertex_normals=np.concatenate(self.vn).astype(np.float32),
                face_smooth=np.concatenate(self.smooth),
                objects=self.objects,
                **kw,
            )
        face_material = []
        for (m, nf), alb in zip(self.mat, self.alb):
            if m is None:
                if np.ptp(alb, axis=0).max() > 0:
                    raise ValueError("a mesh without a material must have one albedo for all its faces when other "
                                     "meshes have materials, got per-face albedo")
                m = Material(name="albedo", base_color_factor=(*(float(c) for c in alb[0]), 1.0),
                             metallic_factor=0.0, roughness_factor=1.0)
            face_material.append(np.full(nf, self._material_index(m), dtype=np.int32))
        faces = np.concatenate(self.f).astype(np.int64)
        vertices = np.concatenate(self.v)
        normals = np.concatenate(self.vn)
        uvs = np.concatenate([u if u is not None else np.zeros((v.shape[0], 2)) for u, v in zip(self.uv, self.v)])
        face_material = np.concatenate(face_material)
        table = MaterialTable.build(self.materials, len(self.images))
        albedo = face_material_colors(faces, face_material, table, self.images, uvs, slot="base_color")
        return Scene(
            vertices=vertices.astype(np.float32),
            faces=faces.astype(np.int32),
            face_albedo=albedo,
            face_emission=np.concatenate(self.emi).astype(np.float32),
            vertex_normals=normals.astype(np.float32),
            face_smooth=np.concatenate(self.smooth),
            objects=self.objects,
            uvs=uvs.astype(np.float32),
            tangents=vertex_tangents(vertices, faces, normals, uvs),
            face_material=face_material,
            materials=table,
            images=list(self.images),
            **kw,
        )


def _any_perpendicular(n: np.ndarray) -> np.ndarray:
    """A unit vector orthogonal to each row of ``n`` ((1, 0, 0) where ``n`` is zero)."""
    a = np.where((np.abs(n[:, 0]) < 0.9)[:, None], [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t = a - n * np.sum(a * n, axis=1, keepdims=True)
    ln = np.linalg.norm(t, axis=1, keepdims=True)
    return np.where(ln > 1e-12, t / np.maximum(ln, 1e-30), [[1.0, 0.0, 0.0]])


def vertex_tangents(vertices, faces, normals, uvs) -> np.ndarray:
    """Per-vertex tangents (V, 4) float32 from the UVs: each triangle's unit ``dP/du`` and ``dP/dv`` (solved from
    its edges and UV differences), weighted by its area and summed over the triangles of a vertex; the tangent
    made orthogonal to the vertex normal (Gram-Schmidt; any perpendicular where it vanishes or the UVs are
    degenerate); w = the sign that makes ``w * cross(n, t)`` point along ``-dP/dv`` (the image's top, glTF's v
    being down). A vertex with a zero normal uses the direction of its faces' summed geometric normals."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    uv = np.asarray(uvs, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    p0, p1, p2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    e1, e2 = p1 - p0, p2 - p0
    d1, d2 = uv[f[:, 1]] - uv[f[:, 0]], uv[f[:, 2]] - uv[f[:, 0]]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    ok = np.abs(det) > 1e-20
    r = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)[:, None]
    dpdu = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * r
    dpdv = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * r
    fn = np.cross(e1, e2)
    area = 0.5 * np.linalg.norm(fn, axis=1, keepdims=True)
    du = dpdu / np.maximum(np.linalg.norm(dpdu, axis=1, keepdims=True), 1e-30) * area
    dv = dpdv / np.maximum(np.linalg.norm(dpdv, axis=1, keepdims=True), 1e-30) * area
    tu, tv, gn = np.zeros_like(v), np.zeros_like(v), np.zeros_like(v)
    for j in range(3):
        np.add.at(tu, f[:, j], du)
        np.add.at(tv, f[:, j], dv)
        np.add.at(gn, f[:, j], fn)
    ln = np.linalg.norm(n, axis=1, keepdims=True)
    gl = np.linalg.norm(gn, axis=1, keepdims=True)
    n = np.where(ln > 1e-12, n / np.maximum(ln, 1e-30), gn / np.maximum(gl, 1e-30))
    t = tu - n * np.sum(tu * n, axis=1, keepdims=True)
    tl = np.linalg.norm(t, axis=1, keepdims=True)
    t = np.where(tl > 1e-9 * np.maximum(np.linalg.norm(tu, axis=1, keepdims=True), 1e-30), t / np.maximum(tl, 1e-30),
                 _any_perpendicular(n))
    w = np.where(np.sum(np.cross(n, t) * -tv, axis=1) < 0, -1.0, 1.0)
    return np.concatenate([t, w[:, None]], axis=1).astype(np.float32)


def _orbit_path(base: Camera, amplitude_deg: float, period_s: float):
    """Camera path swinging the eye about the target around the vertical axis."""
    eye, tgt = np.asarray(base.eye), np.asarray(base.target)

    def path(t: float) -> Camera:
        a = math.radians(amplitude_deg) * math.sin(2.0 * math.pi * t / period_s)
        e = tgt + rot_y(a) @ (eye - tgt)
        return Camera(eye=tuple(e), target=base.target, up=base.up, fov_y_deg=base.fov_y_deg)

    return path


# ---------------------------------------------------------------------------------------------------
WHITE = (0.725, 0.71, 0.68)
RED = (0.63, 0.065, 0.05)
GREEN = (0.14, 0.45, 0.091)


def _cornell_builder(area_light: bool = False, motion: bool = False) -> tuple:
    b = SceneBuilder()
    # box [-1, 1] x [0, 2] x [-1, 1], open towards +z; normals point inwards
    b.add_quad((-1, 0, -1), (0, 0, 2), (2, 0, 0), WHITE, name="floor")
    b.add_quad((-1, 2, -1), (2, 0, 0), (0, 0, 2), WHITE, name="ceiling")
    b.add_quad((-1, 0, -1), (2, 0, 0), (0, 2, 0), WHITE, name="back")
    b.add_quad((-1, 0, -1), (0, 2, 0), (0, 0, 2), RED, name="left")
    b.add_quad((1, 0, -1), (0, 0, 2), (0, 2, 0), GREEN, name="right")
    b.add_box((-0.34, 0.6, -0.3), (0.6, 1.2, 0.6), WHITE, yaw_rad=math.radians(18), name="tall_block")
    short_motion = None
    if motion:
        def short_motion(t):
            # slide the short block left-right (0.4 m amplitude, 4 s period) about its rest place
            return translation((0.4 * math.sin(2.0 * math.pi * t / 4.0), 0.0, 0.0))
    b.add_box((0.36, 0.3, 0.32), (0.6, 0.6, 0.6), WHITE, yaw_rad=math.radians(-17), name="short_block",
              motion=short_motion)
    lights = [Light(kind="spot", position=(0.0, 1.97, 0.0), direction=(0.0, -1.0, 0.0), cone_deg=60.0,
                    intensity=(9.0, 8.3, 7.2), penumbra=0.3)]
    areas = []
    if area_light:
        areas.append(AreaLight(corner=(-0.25, 1.99, -0.25), edge_u=(0.5, 0.0, 0.0), edge_v=(0.0, 0.0, 0.5),
                               radiance=(6.0, 5.6, 5.0)))
    cam = Camera(eye=(0.0, 1.0, 3.4), target=(0.0, 1.0, 0.0), up=(0.0, 1.0, 0.0), fov_y_deg=45.0)
    return b, lights, areas, cam


def cornell(area_light: bool = False, motion: bool = False, bvh_constructor: str = "auto",
            bvh_leaf_size: Optional[int] = None) -> Scene:
    """Cornell box, 2 x 2 x 2 m, open at +z; red left wall, green right wall; a tall and a short block;
    a spot light under the ceiling pointing down. ``area_light=True`` adds a 0.5 x 0.5 m area light 1 cm under
    the ceiling, emitting downwards; ``motion=True`` slides the short block."""
    check_bool("area_light", area_light)
    check_bool("motion", motion)
    check_bvh(bvh_constructor, bvh_leaf_size)
    b, lights, areas, cam = _cornell_builder(area_light, motion)
    return b.build(lights=lights, area_lights=areas, camera=cam, camera_path=_orbit_path(cam, 12.0, 6.0),
                   name="cornell" + ("+motion" if motion else ""), bvh_constructor=bvh_constructor,
                   bvh_leaf_size=bvh_leaf_size)


def bunny_in_box(path=None, bvh_constructor: str = "auto",
                 bvh_leaf_size: Optional[int] = None) -> Scene:
    """Cornell box with the Stanford bunny (0.9 m tall) replacing the tall block."""
    check_bvh(bvh_constructor, bvh_leaf_size)
    p = Path(path) if path is not None else find_named_mesh("bunny")
    if p is None:
        raise ValueError("bunny-in-box: " + named_mesh_help("bunny"))
    v, f, _, vn = load_mesh_arrays(p)
    b = SceneBuilder()
    b.add_quad((-1, 0, -1), (0, 0, 2), (2, 0, 0), WHITE, name="floor")
    b.add_quad((-1, 2, -1), (2, 0, 0), (0, 0, 2), WHITE, name="ceiling")
    b.add_quad((-1, 0, -1), (2, 0, 0), (0, 2, 0), WHITE, name="back")
    b.add_quad((-1, 0, -1), (0, 2, 0), (0, 0, 2), RED, name="left")
    b.add_quad((1, 0, -1), (0, 0, 2), (0, 2, 0), GREEN, name="right")
    lo, hi = v.min(0), v.max(0)
    s = 0.9 / max(hi[1] - lo[1], 1e-12)
    v = (v - np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])) * s + np.array([-0.15, 0.0, -0.1])
    b.add_mesh(v, f, WHITE, normals=vn, smooth=vn is not None, name="bunny")
    lights = [Light(kind="spot", position=(0.0, 1.97, 0.0), direction=(0.0, -1.0, 0.0), cone_deg=60.0,
                    intensity=(9.0, 8.3, 7.2), penumbra=0.3)]
    cam = Camera(eye=(0.0, 1.0, 3.4), target=(0.0, 0.8, 0.0), up=(0.0, 1.0, 0.0), fov_y_deg=45.0)
    return b.build(lights=lights, camera=cam, camera_path=_orbit_path(cam, 12.0, 6.0), name="bunny-in-box",
                   bvh_constructor=bvh_constructor, bvh_leaf_size=bvh_leaf_size)


# ---------------------------------------------------------------------------------------------------
def _exposed_faces(occ: np.ndarray, color_of):
    """Quads of the faces of a voxel occupancy grid (X, Y, Z) that border empty space, as triangles.

    ``color_of(cells (N, 3) int, normal_axis, sign) -> (N, 3)`` colours each quad. Returns v, f, albedo."""
    verts, faces, cols = [], [], []
    X, Y, Z = occ.shape
    pad = np.pad(occ, 1, constant_values=False)
    nv = 0
    unit = np.eye(3, dtype=np.int64)
    for axis in range(3):
        for sign in (-1, 1):
            sl_n = [slice(1, -1)] * 3
            sl_n[axis] = slice(1 + sign, 1 + sign + occ.shape[axis])
            nb = pad[tuple(sl_n)]
            exposed = occ & ~nb
            cells = np.argwhere(exposed)
            if cells.size == 0:
                continue
            n = cells.shape[0]
            a1, a2 = [a for a in range(3) if a != axis]
            base = cells.astype(np.float64) + (unit[axis] if sign > 0 else 0)
            c0 = base
            c1 = base + unit[a1]
            c2 = base + unit[a1] + unit[a2]
            c3 = base + unit[a2]
            quad = np.stack([c0, c1, c2, c3], axis=1).reshape(-1, 3)
            idx = nv + np.arange(n)[:, None] * 4
            # winding: outward normal along sign * axis
            # cross(unit[a1], unit[a2]) is +axis for axis 0 and 2, -axis for axis 1
            if sign * (-1 if axis == 1 else 1) > 0:
                tri = np.concatenate([idx + [[0, 1, 2]], idx + [[0, 2, 3]]], axis=0)
            else:
                tri = np.concatenate([idx + [[0, 2, 1]], idx + [[0, 3, 2]]], axis=0)
            col = color_of(cells, axis, sign)
            verts.append(quad)
            faces.append(tri)
            cols.append(np.concatenate([col, col], axis=0))
            nv += 4 * n
    return np.concatenate(verts), np.concatenate(faces), np.concatenate(cols)


def city(seed: int = 7, size: int = 224, block: int = 16, street: int = 4, max_height: int = 44,
         bvh_constructor: str = "auto",
         bvh_leaf_size: Optional[int] = None) -> Scene:
    """Seeded voxel city (1 voxel = 1 m): city blocks of buildings with window recesses and roof detail.

    The default has about 1.2M triangles. Deterministic for a given ``seed`` (in [0, 2^32 - 1]). ``size`` in
    [1, 1024] voxels, ``block`` in [9, 256], ``street`` in [0, 256], ``max_height`` in [5, 128]."""
    seed = check_int_range("seed", seed, 0, 2**32 - 1)
    size = check_int_range("size", size, 1, 1024)
    block = check_int_range("block", block, 9, 256)
    street = check_int_range("street", street, 0, 256)
    max_height = check_int_range("max_height", max_height, 5, 128)
    check_bvh(bvh_constructor, bvh_leaf_size)
    rng = np.random.default_rng(seed)
    H = max_height + 2
    occ = np.zeros((size, H, size), dtype=bool)
    occ[:, 0, :] = True  # ground slab
    bid = np.full((size, size), -1, dtype=np.int64)
    n_build = 0
    period = block + street
    for bx in range(0, size - block + 1, period):
        for bz in range(0, size - block + 1, period):
            # split each city block into 2-4 lots per side
            xs = np.sort(rng.choice(np.arange(4, block - 3), size=rng.integers(1, 3), replace=False))
            zs = np.sort(rng.choice(np.arange(4, block - 3), size=rng.integers(1, 3), replace=False))
            xcuts = [0, *xs.tolist(), block]
            zcuts = [0, *zs.tolist(), block]
            for i in range(len(xcuts) - 1):
                for j in range(len(zcuts) - 1):
                    x0, x1 = bx + xcuts[i], bx + xcuts[i + 1] - 1  # 1-voxel gap between buildings
                    z0, z1 = bz + zcuts[j], bz + zcuts[j + 1] - 1
                    if x1 - x0 < 2 or z1 - z0 < 2:
                        continue
                    h = int(rng.integers(4, max_height))
                    occ[x0:x1, 1:h + 1, z0:z1] = True
                    bid[x0:x1, z0:z1] = n_build
                    n_build += 1
                    # roof detail: a smaller box on top, sometimes
                    if rng.random() < 0.5 and x1 - x0 > 4 and z1 - z0 > 4 and h + 3 < H:
                        occ[x0 + 1:x1 - 1, h + 1:h + 3, z0 + 1:z1 - 1] = True
    # window recesses: carve every other voxel on every other floor of the outer shell
    ys = np.arange(H)
    win = np.zeros_like(occ)
    xg, yg, zg = np.meshgrid(np.arange(size), ys, np.arange(size), indexing="ij")
    pattern = ((yg % 3) == 2) & (((xg + zg) % 2) == 0) & (yg > 1)
    interior = occ.copy()
    interior[1:-1, :, 1:-1] = (
        occ[1:-1, :, 1:-1] & occ[:-2, :, 1:-1] & occ[2:, :, 1:-1] & occ[1:-1, :, :-2] & occ[1:-1, :, 2:]
    )
    shell = occ & ~interior
    win = shell & pattern & (yg < H - 3)
    # keep at least the top of the building: only carve where the voxel above is occupied
    above = np.zeros_like(occ)
    above[:, :-1, :] = occ[:, 1:, :]
    occ = occ & ~(win & above)
    palette = np.array([[0.75, 0.72, 0.66], [0.62, 0.55, 0.5], [0.55, 0.6, 0.68], [0.8, 0.78, 0.74],
                        [0.66, 0.48, 0.38], [0.5, 0.52, 0.55], [0.72, 0.66, 0.52]], dtype=np.float32)
    bcol = palette[rng.integers(0, len(palette), size=max(n_build, 1))]

    def color_of(cells, axis, sign):
        x, y, z = cells[:, 0], cells[:, 1], cells[:, 2]
        b_ = bid[x, z]
        col = np.where(b_[:, None] >= 0, bcol[np.maximum(b_, 0)], np.array([0.3, 0.3, 0.32], dtype=np.float32))
        ground = y == 0
        street_c = np.array([0.22, 0.22, 0.24], dtype=np.float32)
        col = np.where(ground[:, None], street_c, col)
        # window backs (faces inside recesses) are dark glass
        glass = (axis != 1) & ((y % 3) == 2) & ~ground
        col = np.where(glass[:, None], col * 0.35 + np.array([0.05, 0.08, 0.12], dtype=np.float32), col)
        jitter = 0.92 + 0.08 * ((x * 7 + y * 13 + z * 3) % 5) / 4.0
        return (col * jitter[:, None]).astype(np.float32)

    v, f, alb = _exposed_faces(occ, color_of)
    c = size / 2.0
    v = v - np.array([c, 0.0, c])
    b = SceneBuilder()
    b.add_mesh(v, f, np.clip(alb, 0, 1), name="city")
    sun = np.array([0.35 * size, 4.0 * max_height, 0.25 * size])
    fill = np.array([-0.4 * size, 2.0 * max_height, 0.5 * size])
    lights = [
        Light(kind="point", position=tuple(sun), intensity=tuple(np.array([1.0, 0.95, 0.85]) * 2.5 * (sun @ sun))),
        Light(kind="point", position=tuple(fill), intensity=tuple(np.array([0.45, 0.5, 0.6]) * 1.0 * (fill @ fill))),
        Light(kind="spot", position=(-0.1 * size, 1.5 * max_height, -0.1 * size), direction=(0.3, -1.0, 0.25),
              cone_deg=35.0, intensity=(1.5e4, 1.3e4, 1.1e4)),
    ]
    cam = Camera(eye=(-0.45 * size, 1.3 * max_height, 0.45 * size), target=(0.05 * size, 0.0, -0.05 * size),
                 up=(0.0, 1.0, 0.0), fov_y_deg=60.0)
    return b.build(lights=lights, camera=cam, camera_path=_orbit_path(cam, 10.0, 10.0), name="city",
                   bvh_constructor=bvh_constructor, bvh_leaf_size=bvh_leaf_size)


# ---------------------------------------------------------------------------------------------------
# a 5 x 5 bitmap font of Snellen optotypes (rows top to bottom, '#' = ink)
_GLYPHS = {
    "E": ["#####", "#....", "####.", "#....", "#####"],
    "F": ["#####", "#....", "####.", "#....", "#...."],
    "P": ["####.", "#...#", "####.", "#....", "#...."],
    "T": ["#####", "..#..", "..#..", "..#..", "..#.."],
    "O": [".###.", "#...#", "#...#", "#...#", ".###."],
    "Z": ["#####", "...#.", "..#..", ".#...", "#####"],
    "L": ["#....", "#....", "#....", "#....", "#####"],
    "D": ["####.", "#...#", "#...#", "#...#", "####."],
    "C": [".####", "#....", "#....", "#....", ".####"],
}
INK = (0.04, 0.04, 0.04)
PAPER = (0.85, 0.85, 0.82)


def _panel(b: SceneBuilder, origin, width: float, height: float, seed: int):
    """One chart panel on the plane z = origin[2] (facing +z): gratings of several periods (vertical,
    horizontal, diagonal-ish checker) on the left, letter rows of decreasing size on the right."""
    ox, oy, oz = origin
    rng = np.random.default_rng(seed)
    # gratings: 4 patches stacked, periods halving
    gw = width * 0.45
    gh = height / 4.0
    for k in range(4):
        n_bars = 4 * (2**k)
        y0 = oy + height - (k + 1) * gh
        bw = gw / n_bars
        for i in range(n_bars):
            col = INK if i % 2 == 0 else PAPER
            if k % 2 == 0:  # vertical bars
                b.add_quad((ox + i * bw, y0, oz), (bw, 0, 0), (0, gh, 0), col)
            else:  # horizontal bars
                bh = gh / n_bars
                b.add_quad((ox, y0 + i * bh, oz), (gw, 0, 0), (0, bh, 0), col)
    # letters: rows of 5 letters, sizes shrinking by 0.6x, tiled exactly in 5 x 5 cells (no overlap)
    lx0 = ox + width * 0.5
    lw = width * 0.5
    y = oy + height
    size = lw / 6.0
    letters = list(_GLYPHS)
    while size > 0.01 and y - size > oy:
        row_y = y - size
        gap = size / 5.0
        n = min(5, int(lw // (size + gap)))
        # paper strip behind the row's gaps
        b.add_quad((lx0, row_y - gap, oz - 1e-4), (lw, 0, 0), (0, size + gap, 0), PAPER)
        for i in range(n):
            g = _GLYPHS[letters[int(rng.integers(0, len(letters)))]]
            cell = size / 5.0
            for r in range(5):
                for c in range(5):
                    col = INK if g[r][c] == "#" else PAPER
                    b.add_quad((lx0 + i * (size + gap) + c * cell, row_y + (4 - r) * cell, oz), (cell, 0, 0),
                               (0, cell, 0), col)
        y = row_y - gap
        size *= 0.6


def eyechart(seed: int = 3, bvh_constructor: str = "auto",
             bvh_leaf_size: Optional[int] = None) -> Scene:
    """Three chart panels at 4, 8 and 14 m from the camera, plus a floor: gratings of 4 periods
    (vertical / horizontal bars) and Snellen-like letter rows shrinking to a few millimetres. ``seed`` in
    [0, 2^32 - 3]."""
    seed = check_int_range("seed", seed, 0, 2**32 - 3)
    check_bvh(bvh_constructor, bvh_leaf_size)
    b = SceneBuilder()
    b.add_quad((-20, 0, 10), (40, 0, 0), (0, 0, -40), (0.35, 0.33, 0.3), name="floor")
    _panel(b, (-3.2, 0.4, 0.0), 3.0, 2.2, seed)  # 4 m from the eye
    _panel(b, (0.6, 0.5, -4.0), 3.6, 2.6, seed + 1)  # 8 m
    _panel(b, (-1.0, 2.9, -10.0), 5.0, 3.5, seed + 2)  # 14 m
    lights = [
        Light(kind="point", position=(0.0, 6.0, 3.0), intensity=(60.0, 60.0, 58.0)),
        Light(kind="spot", position=(2.0, 5.0, 0.0), direction=(-0.1, -0.4, -1.0), cone_deg=40.0,
              intensity=(120.0, 118.0, 110.0)),
    ]
    cam = Camera(eye=(0.0, 1.6, 4.0), target=(0.0, 1.8, -4.0), up=(0.0, 1.0, 0.0), fov_y_deg=60.0)
    return b.build(lights=lights, camera=cam, camera_path=_orbit_path(cam, 6.0, 8.0), name="eyechart",
                   bvh_constructor=bvh_constructor, bvh_leaf_size=bvh_leaf_size)


def _earth_albedo(centroids: np.ndarray) -> np.ndarray:
    """Procedural continents from a few seeded sinusoids of the unit direction; ice at the poles."""
    rng = np.random.default_rng(11)
    d = centroids / np.linalg.norm(centroids, axis=1, keepdims=True)
    h = np.zeros(d.shape[0])
    for _ in range(6):
        k = rng.normal(size=3) * rng.uniform(1.5, 4.0)
        h += np.sin(d @ k + rng.uniform(0, 2 * np.pi)) / 3.0
    ocean = np.array([0.05, 0.15, 0.45])
    land = np.array([0.2, 0.42, 0.12])
    desert = np.array([0.62, 0.52, 0.32])
    ice = np.array([0.92, 0.94, 0.96])
    col = np.where((h > 0.15)[:, None], np.where((h > 0.55)[:, None], desert, land), ocean)
    col = np.where((np.abs(d[:, 1]) > 0.85)[:, None], ice, col)
    return col.astype(np.float32)


def earth(spin: bool = True, bvh_constructor: str = "auto",
          bvh_leaf_size: Optional[int] = None) -> Scene:
    """Low-poly Earth: a 24 x 21 UV sphere (960 triangles) of radius 1 m with a procedural albedo, lit by
    a distant sun; ``spin`` rotates it once per 12 s."""
    check_bool("spin", spin)
    check_bvh(bvh_constructor, bvh_leaf_size)
    b = SceneBuilder()
    motion = (lambda t: _rot4(rot_y(2.0 * math.pi * t / 12.0))) if spin else None
    b.add_sphere((0.0, 0.0, 0.0), 1.0, 24, 21, albedo_fn=_earth_albedo, smooth=True, name="earth", motion=motion)
    lights = [Light(kind="point", position=(30.0, 10.0, 25.0), intensity=(2200.0, 2150.0, 2000.0))]
    cam = Camera(eye=(0.0, 0.4, 3.2), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_y_deg=45.0)
    return b.build(lights=lights, camera=cam, camera_path=_orbit_path(cam, 20.0, 12.0), name="earth",
                   bvh_constructor=bvh_constructor, bvh_leaf_size=bvh_leaf_size)


def _rot4(r3):
    m = np.eye(4)
    m[:3, :3] = r3
    return m


# ---------------------------------------------------------------------------------------------------
# procedural textures for "room" (linear values, made in NumPy at load time)


def _srgb(c) -> np.ndarray:
    """sRGB-encoded colour values -> linear (the exact EOTF)."""
    from .io.images import srgb_to_linear

    return srgb_to_linear(np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0))


def _tile_noise(rng, size: int, cells_y: int, cells_x: int, octaves: int = 3) -> np.ndarray:
    """Smooth value noise in [0, 1] on a size x size grid that tiles seamlessly: ``octaves`` random lattices of
    ``cells_y x cells_x`` cells (doubling per octave, halving in weight), smoothstep-interpolated with wrap-around."""
    out = np.zeros((size, size))
    amp = total = 0.0
    amp = 1.0
    for o in range(octaves):
        cy, cx = cells_y * 2**o, cells_x * 2**o
        lat = rng.random((cy, cx))

        def axis(c):
            x = np.arange(size) * c / size
            i0 = np.floor(x).astype(np.int64)
            f = x - i0
            return i0 % c, (i0 + 1) % c, f * f * (3.0 - 2.0 * f)

        y0, y1, fy = axis(cy)
        x0, x1, fx = axis(cx)
        rows = lat[y0] * (1.0 - fy)[:, None] + lat[y1] * fy[:, None]
        out += amp * (rows[:, x0] * (1.0 - fx)[None, :] + rows[:, x1] * fx[None, :])
        total += amp
        amp *= 0.5
    return out / total


def _brick_textures(size: int = 512, seed: int = 5) -> tuple:
    """A running-bond brick wall: (base colour (size, size, 3) linear, tangent-space normal map (size, size, 3)
    encoded as ``0.5 n + 0.5``). 16 courses of 4 bricks per tile, 5-texel mortar joints, bricks bevelled over
    3 texels, each brick tinted by the seed."""
    rng = np.random.default_rng(seed)
    courses, per_row, mortar = 16, 4, 5
    ch, bw = size // courses, size // per_row
    y, x = np.mgrid[0:size, 0:size]
    row = y // ch
    xs = (x + (row % 2) * (bw // 2)) % size
    col = xs // bw
    lx, ly = xs % bw, y % ch
    # texels from the nearest mortar edge (mortar at the left and top of every brick cell), < 0 in the mortar
    d = np.minimum(np.minimum(lx - mortar + 0.5, bw - lx - 0.5), np.minimum(ly - mortar + 0.5, ch - ly - 0.5))
    in_mortar = d < 0
    ids = row * per_row + col
    nb = courses * per_row
    tint = rng.uniform(0.72, 1.1, nb)[ids]
    warm = rng.uniform(-0.05, 0.05, nb)[ids]
    coarse = _tile_noise(rng, size, 16, 16, 3)
    fine = rng.random((size, size))
    brick = np.stack([0.60 + warm, 0.28 + 0.4 * warm, 0.20 * np.ones_like(warm)], axis=-1) * tint[..., None]
    brick *= (0.85 + 0.3 * coarse + 0.08 * fine)[..., None]
    mortar_c = np.array([0.66, 0.64, 0.60]) * (0.9 + 0.15 * coarse + 0.05 * fine)[..., None]
    base = np.where(in_mortar[..., None], mortar_c, brick)
    height = np.clip(d / 3.0, 0.0, 1.0) + 0.08 * fine * ~in_mortar
    dhdx = (np.roll(height, -1, axis=1) - np.roll(height, 1, axis=1)) * 0.5
    dhdy = (np.roll(height, -1, axis=0) - np.roll(height, 1, axis=0)) * 0.5
    # tangent space: +x along u (columns), +y towards the image's top (rows decreasing): dh/dup = -dh/drow
    s = 2.0
    n = np.stack([-s * dhdx, s * dhdy, np.ones_like(dhdx)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return _srgb(base).astype(np.float32), (0.5 * n + 0.5).astype(np.float32)


def _wood_textures(size: int = 512, seed: int = 9) -> tuple:
    """Floor boards along u: (base colour (size, size, 3) linear, metallic-roughness (size, size, 3): R 1, G the
    roughness, B 0). 8 rows of boards 64 texels wide, two boards per row per tile with staggered joints, grain
    streaks from anisotropic noise, 2-texel dark gaps."""
    rng = np.random.default_rng(seed)
    rows, per_row, gap = 8, 2, 2
    bh, bl = size // rows, size // per_row
    y, x = np.mgrid[0:size, 0:size]
    plank = y // bh
    offsets = rng.integers(0, bl, rows)
    bx = (x + offsets[plank]) % size
    board = plank * per_row + bx // bl
    lx, ly = bx % bl, y % bh
    in_gap = (ly < gap) | (lx < gap)
    streaks = _tile_noise(rng, size, 16, 2, 3)  # long along u
    fibres = _tile_noise(rng, size, 64, 8, 2)
    phase = rng.random(rows * per_row)[board]
    tint = rng.uniform(0.85, 1.1, rows * per_row)[board]
    grain = 0.5 + 0.5 * np.sin(2.0 * np.pi * (3.0 * ly / bh + 2.5 * streaks + phase))
    t = np.clip(0.75 * grain ** 2 + 0.25 * fibres, 0.0, 1.0)[..., None]
    light, dark = np.array([0.72, 0.50, 0.30]), np.array([0.44, 0.27, 0.14])
    base = (light * (1.0 - t) + dark * t) * tint[..., None]
    base = np.where(in_gap[..., None], np.array([0.12, 0.08, 0.05]), base)
    rough = np.where(in_gap, 0.9, 0.5 + 0.25 * grain)
    mr = np.stack([np.ones_like(rough), rough, np.zeros_like(rough)], axis=-1)
    return _srgb(base).astype(np.float32), mr.astype(np.float32)


def _picture_texture(width: int = 512, height: int = 320) -> np.ndarray:
    """A landscape painting (height, width, 3) linear: evening sky with a sun, two mountain ranges, a lake that
    mirrors the sky."""
    y, x = np.mgrid[0:height, 0:width]
    u, v = (x + 0.5) / width, (y + 0.5) / height
    horizon = 0.62

    def sky(vv):
        t = np.clip(vv / horizon, 0.0, 1.0)[..., None]
        return np.array([0.35, 0.55, 0.85]) * (1.0 - t) + np.array([0.98, 0.74, 0.45]) * t

    img = sky(v)
    sun = (u - 0.72) ** 2 + ((v - 0.36) * height / width) ** 2 < 0.05 ** 2
    img = np.where(sun[..., None], np.array([1.0, 0.93, 0.62]), img)
    far = 0.42 + 0.07 * np.sin(2 * np.pi * 2 * u + 1.0) + 0.04 * np.sin(2 * np.pi * 5 * u + 2.0) \
        + 0.015 * np.sin(2 * np.pi * 13 * u)
    near = 0.53 + 0.04 * np.sin(2 * np.pi * 3 * u + 4.0) + 0.02 * np.sin(2 * np.pi * 9 * u + 0.5)
    img = np.where(((v > far) & (v < horizon))[..., None], np.array([0.36, 0.40, 0.52]), img)
    img = np.where(((v > near) & (v < horizon))[..., None], np.array([0.24, 0.40, 0.20]), img)
    water = v >= horizon
    ripple = 0.92 + 0.08 * np.sin(2 * np.pi * (40 * v + 3 * np.sin(2 * np.pi * 4 * u)))
    mirrored = sky(2 * horizon - v) * 0.6 + np.array([0.06, 0.14, 0.22]) * 0.4
    img = np.where(water[..., None], mirrored * ripple[..., None], img)
    return _srgb(img).astype(np.float32)


def _sky_environment(sun_dir, width: int = 256, height: int = 128, sun_irradiance: float = 3.0,
                     sun_radius_deg: float = 1.5) -> np.ndarray:
    """An equirectangular sky (height, width, 3) of linear radiance in :class:`foveawarp.scene.Scene`'s
    environment convention: blue at the zenith, pale at the horizon, a dim ground below it, and a sun disk of
    ``sun_radius_deg`` around the unit ``sun_dir`` whose radiance makes its irradiance at normal incidence
    (the sum of radiance times texel solid angle) ``sun_irradiance``."""
    theta = (np.arange(height) + 0.5) / height * np.pi
    phi = (np.arange(width) + 0.5) / width * 2.0 * np.pi
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    d = np.stack([np.sin(th) * np.sin(ph), np.cos(th), -np.sin(th) * np.cos(ph)], axis=-1)
    up = np.clip(d[..., 1], 0.0, 1.0) ** 0.5
    zenith, horizon = np.array([0.22, 0.42, 0.95]), np.array([0.95, 0.98, 1.05])
    img = horizon * (1.0 - up[..., None]) + zenith * up[..., None]
    img = np.where((d[..., 1] < 0)[..., None], np.array([0.14, 0.12, 0.10]), img)
    s = np.asarray(sun_dir, dtype=np.float64)
    s = s / np.linalg.norm(s)
    cosang = d @ s
    disk = cosang > math.cos(math.radians(sun_radius_deg))
    if not disk.any():
        disk = cosang >= cosang.max()
    texel_sr = (2.0 * np.pi / width) * (np.pi / height) * np.sin(th)
    img[disk] += np.array([1.0, 0.93, 0.82]) * (sun_irradiance / float(texel_sr[disk].sum()))
    return img.astype(np.float32)


def _quad_mesh(corner, edge_u, edge_v, tiles=(1.0, 1.0)) -> tuple:
    """A parallelogram as (vertices, faces, normals, uvs): front side ``cross(edge_u, edge_v)``; u runs along
    ``edge_u`` over ``tiles[0]`` texture repeats, v down from the far end of ``edge_v`` (so images stand upright
    when ``edge_v`` points up)."""
    c, eu, ev = (np.asarray(a, dtype=np.float64) for a in (corner, edge_u, edge_v))
    verts = np.stack([c, c + eu, c + eu + ev, c + ev])
    n = np.cross(eu, ev)
    n = np.tile(n / np.linalg.norm(n), (4, 1))
    s, t = np.array([0.0, 1.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0, 1.0])
    uvs = np.stack([s * tiles[0], (1.0 - t) * tiles[1]], axis=1)
    return verts, np.array([[0, 1, 2], [0, 2, 3]]), n, uvs


def _uv_sphere_mesh(center, radius: float, n_lon: int = 32, n_lat: int = 16) -> tuple:
    """A UV sphere with a seam column of its own (u = longitude / 2 pi, v = polar angle / pi from the north pole):
    (vertices, faces, normals, uvs); the triangles that would collapse at the poles are left out."""
    th = np.linspace(0.0, np.pi, n_lat + 1)
    ph = np.linspace(0.0, 2.0 * np.pi, n_lon + 1)
    t, p = np.meshgrid(th, ph, indexing="ij")
    n = np.stack([np.sin(t) * np.cos(p), np.cos(t), -np.sin(t) * np.sin(p)], axis=-1).reshape(-1, 3)
    uvs = np.stack([p / (2.0 * np.pi), t / np.pi], axis=-1).reshape(-1, 2)
    idx = np.arange((n_lat + 1) * (n_lon + 1)).reshape(n_lat + 1, n_lon + 1)
    a, b = idx[:-1, :-1], idx[:-1, 1:]
    c, d = idx[1:, :-1], idx[1:, 1:]
    top = np.stack([a, c, d], axis=-1)[1:].reshape(-1, 3)  # row 0 would be degenerate at the north pole
    bot = np.stack([a, d, b], axis=-1)[:-1].reshape(-1, 3)  # the last row at the south pole
    faces = np.concatenate([np.stack([a[0], c[0], d[0]], axis=-1), top, bot])
    return n * radius + np.asarray(center, dtype=np.float64), faces, n, uvs


def room(bvh_constructor: str = "auto", bvh_leaf_size: Optional[int] = None) -> Scene:
    """A textured room, 5 x 3 x 5.5 m (x in [-2.5, 2.5], y in [0, 3], z in [-3.5, 2]), open on its +x side to
    a grass field under a sky: a brick back wall (base colour and normal map, 1 m tiles), a wooden floor (base
    colour and roughness, 2 m tiles), plaster side walls and ceiling, a landscape painting in a gilded frame on
    the left wall, a polished metal sphere (metallic 1, roughness 0.12), a red rough plastic box (roughness
    0.75) and a blue plastic ball on it (roughness 0.45).

    Lights: a sun (a narrow spot from outside through the open side, irradiance 3 where it lands), a ceiling
    lamp (point) and a cool fill from the sky side (point); ``environment`` is a matching sky with a sun disk
    of the same direction and irradiance (``_sky_environment``). The camera swings 14 degrees about its target
    over 10 s. Textures are made in NumPy at load time (4 images of 512 x 512, one of 512 x 320)."""
    check_bvh(bvh_constructor, bvh_leaf_size)
    b = SceneBuilder()
    brick, brick_n = _brick_textures()
    wood, wood_mr = _wood_textures()
    i_brick, i_brick_n = b.add_image(brick), b.add_image(brick_n)
    i_wood, i_wood_mr = b.add_image(wood), b.add_image(wood_mr)
    i_pic = b.add_image(_picture_texture())
    m_brick = Material("brick", base_color_texture=TextureRef(i_brick, color_space="srgb"),
                       normal_texture=TextureRef(i_brick_n), metallic_factor=0.0, roughness_factor=0.9)
    m_wood = Material("wood floor", base_color_texture=TextureRef(i_wood, color_space="srgb"),
                      metallic_roughness_texture=TextureRef(i_wood_mr), metallic_factor=0.0, roughness_factor=1.0)
    m_picture = Material("painting", base_color_texture=TextureRef(i_pic, wrap_s="clamp", wrap_t="clamp",
                                                                   color_space="srgb"),
                         metallic_factor=0.0, roughness_factor=0.6)
    m_plaster = Material("plaster", base_color_factor=(0.70, 0.68, 0.63, 1.0), metallic_factor=0.0,
                         roughness_factor=0.95)
    m_ceiling = Material("ceiling", base_color_factor=(0.80, 0.79, 0.76, 1.0), metallic_factor=0.0,
                         roughness_factor=0.95)
    m_grass = Material("grass", base_color_factor=(0.16, 0.30, 0.08, 1.0), metallic_factor=0.0, roughness_factor=1.0)
    m_frame = Material("gilded frame", base_color_factor=(0.83, 0.61, 0.28, 1.0), metallic_factor=1.0,
                       roughness_factor=0.35)
    m_metal = Material("polished metal", base_color_factor=(0.95, 0.93, 0.88, 1.0), metallic_factor=1.0,
                       roughness_factor=0.12)
    m_red = Material("red rough plastic", base_color_factor=(0.65, 0.07, 0.05, 1.0), metallic_factor=0.0,
                     roughness_factor=0.75)
    m_blue = Material("blue plastic", base_color_factor=(0.06, 0.18, 0.55, 1.0), metallic_factor=0.0,
                      roughness_factor=0.45)

    def quad(name, material, corner, eu, ev, tiles=(1.0, 1.0)):
        v, f, n, uv = _quad_mesh(corner, eu, ev, tiles)
        b.add_mesh(v, f, None, normals=n, uvs=uv, material=material, name=name)

    quad("floor", m_wood, (-2.5, 0.0, 2.0), (5.0, 0.0, 0.0), (0.0, 0.0, -5.5), (2.5, 2.75))
    quad("ceiling", m_ceiling, (-2.5, 3.0, -3.5), (5.0, 0.0, 0.0), (0.0, 0.0, 5.5))
    quad("back wall", m_brick, (-2.5, 0.0, -3.5), (5.0, 0.0, 0.0), (0.0, 3.0, 0.0), (5.0, 3.0))
    quad("left wall", m_plaster, (-2.5, 0.0, 2.0), (0.0, 0.0, -5.5), (0.0, 3.0, 0.0))
    quad("front wall", m_plaster, (2.5, 0.0, 2.0), (-5.0, 0.0, 0.0), (0.0, 3.0, 0.0))
    quad("field", m_grass, (2.5, 0.0, 40.0), (40.0, 0.0, 0.0), (0.0, 0.0, -80.0))
    # the painting, 1.6 x 1.0 m, 1 cm in front of the left wall, and its frame
    quad("painting", m_picture, (-2.49, 1.05, -0.4), (0.0, 0.0, -1.6), (0.0, 1.0, 0.0))
    frame_bars = (((-2.48, 2.08, -1.2), (0.04, 0.06, 1.72)), ((-2.48, 1.02, -1.2), (0.04, 0.06, 1.72)),
                  ((-2.48, 1.55, -0.37), (0.04, 1.0, 0.06)), ((-2.48, 1.55, -2.03), (0.04, 1.0, 0.06)))
    for i, (c, size) in enumerate(frame_bars):
        b.add_box(c, size, None, material=m_frame, name=f"frame{i}")
    v, f, n, uv = _uv_sphere_mesh((-0.9, 0.4, -1.9), 0.4)
    b.add_mesh(v, f, None, normals=n, smooth=True, uvs=uv, material=m_metal, name="metal sphere")
    b.add_box((0.9, 0.3, -2.3), (0.6, 0.6, 0.6), None, yaw_rad=math.radians(25.0), material=m_red, name="box")
    v, f, n, uv = _uv_sphere_mesh((0.9, 0.85, -2.3), 0.25)
    b.add_mesh(v, f, None, normals=n, smooth=True, uvs=uv, material=m_blue, name="ball")

    sun_pos, sun_aim = np.array([9.0, 8.0, -0.6]), np.array([0.2, 0.0, -1.8])
    sun_d2 = float(np.sum((sun_pos - sun_aim) ** 2))
    lights = [
        Light(kind="spot", position=tuple(sun_pos), direction=tuple(sun_aim - sun_pos), cone_deg=14.0,
              intensity=tuple(np.array([1.0, 0.93, 0.82]) * 3.0 * sun_d2), penumbra=0.3),
        Light(kind="point", position=(0.0, 2.75, -1.2), intensity=(7.0, 6.5, 5.6)),
        Light(kind="point", position=(6.0, 2.5, -1.0), intensity=(8.0, 9.0, 11.0)),
    ]
    cam = Camera(eye=(-0.4, 1.55, 1.5), target=(0.4, 1.15, -2.2), up=(0.0, 1.0, 0.0), fov_y_deg=60.0)
    return b.build(lights=lights, camera=cam, camera_path=_orbit_path(cam, 14.0, 10.0), name="room",
                   environment=_sky_environment(sun_pos - sun_aim), bvh_constructor=bvh_constructor,
                   bvh_leaf_size=bvh_leaf_size)


# ---------------------------------------------------------------------------------------------------
# scene files with materials (glTF, OBJ + MTL, Mitsuba XML)

# a directional light becomes a point light this many scene extents away (irradiance across the scene within 0.1%)
DIRECTIONAL_DISTANCE_EXTENTS = 1000.0


def lights_from_file(file_lights, centre, extent: float) -> tuple:
    """A scene file's lights (``GltfLight``-like: kind, color, intensity, range_m, position, direction,
    inner/outer_cone_rad) as :class:`Light` s, and notes on what was left out: ``(lights, notes)``.

    Units: glTF's photometric values are taken as the renderer's radiometric ones, one to one (the way the
    Khronos glTF Sample Viewer shades them; the tone map sets the exposure): a point or spot light of
    ``intensity`` candela and ``color`` gets ``Light.intensity = color * intensity`` (radiant intensity per
    steradian); a directional light of ``intensity`` lux becomes a point light ``DIRECTIONAL_DISTANCE_EXTENTS *
    extent`` away against its direction from ``centre``, with ``color * intensity * distance^2``, so that its
    irradiance at ``centre`` is ``color * intensity``. Spot cones: ``cone_deg`` = the outer angle in degrees,
    ``penumbra = 1 - inner / outer`` (the smooth falloff then runs between the two angles, as in glTF). glTF's
    ``range`` is not modelled (lights reach everywhere); each light that has one is named in the notes."""
    c = np.asarray(centre, dtype=np.float64)
    dist = DIRECTIONAL_DISTANCE_EXTENTS * max(float(extent), 1e-6)
    lights, notes, ranged = [], [], []
    for i, fl in enumerate(file_lights or []):
        kind = getattr(fl, "kind", None)
        label = f"light {i}" + (f" ({fl.name!r})" if getattr(fl, "name", "") else "")
        power = np.asarray(fl.color, dtype=np.float64) * float(fl.intensity)
        if kind == "point":
            lights.append(Light(kind="point", position=tuple(fl.position), intensity=tuple(power)))
        elif kind == "spot":
            outer = float(fl.outer_cone_rad)
            inner = min(max(float(fl.inner_cone_rad), 0.0), outer)
            lights.append(Light(kind="spot", position=tuple(fl.position), direction=tuple(fl.direction),
                                cone_deg=max(math.degrees(outer), 1e-3),
                                penumbra=1.0 - inner / outer if outer > 0 else 0.0, intensity=tuple(power)))
        elif kind == "directional":
            d = np.asarray(fl.direction, dtype=np.float64)
            pos = c - d / max(float(np.linalg.norm(d)), 1e-30) * dist
            lights.append(Light(kind="point", position=tuple(pos), intensity=tuple(power * dist * dist)))
        else:
            notes.append(f"{label} of kind {kind!r} is not supported (point, spot, directional) and was left out")
            continue
        if getattr(fl, "range_m", None) is not None:
            ranged.append(label)
    if ranged:
        notes.append(f"the range of {', '.join(ranged)} is not modelled: the light reaches the whole scene")
    return lights, notes


def default_lights(camera: Camera, centre, radius: float) -> list:
    """The lights a scene file without any gets: a warm key light (point) above, right of and in front of the
    scene seen from ``camera``, 3 radii from ``centre``, giving an irradiance of 2.5 there, and a cool fill light
    (point) at the camera's eye giving 0.6 there."""
    c = np.asarray(centre, dtype=np.float64)
    eye = np.asarray(camera.eye, dtype=np.float64)
    f = np.asarray(camera.target, dtype=np.float64) - eye
    f /= max(float(np.linalg.norm(f)), 1e-30)
    r = np.cross(f, np.asarray(camera.up, dtype=np.float64))
    r /= max(float(np.linalg.norm(r)), 1e-30)
    u = np.cross(r, f)
    k = -f + 0.9 * u + 0.6 * r
    d_key = 3.0 * max(float(radius), 1e-6)
    key = c + k / np.linalg.norm(k) * d_key
    d_fill2 = max(float(np.sum((eye - c) ** 2)), 1e-12)
    return [Light(kind="point", position=tuple(key), intensity=tuple(np.array([1.0, 0.96, 0.9]) * 2.5 * d_key ** 2)),
            Light(kind="point", position=tuple(eye), intensity=tuple(np.array([0.9, 0.95, 1.0]) * 0.6 * d_fill2))]


def _framing_camera(centre, radius: float, fov_y_deg: float = 40.0) -> Camera:
    """A camera looking at ``centre`` from the front (+z) and a little above, far enough for the bounding sphere
    of ``radius`` to fit the vertical field of view."""
    d = np.array([0.0, 0.35, 1.0])
    d /= np.linalg.norm(d)
    dist = max(float(radius), 1e-6) / math.sin(math.radians(fov_y_deg) / 2.0) * 1.05
    c = np.asarray(centre, dtype=np.float64)
    return Camera(eye=tuple(c + d * dist), target=tuple(c), up=(0.0, 1.0, 0.0), fov_y_deg=fov_y_deg)


def _turntable_path(base: Camera, period_s: float):
    """Camera path circling the target once per ``period_s`` about the vertical axis, at the base camera's height
    and distance."""
    eye, tgt = np.asarray(base.eye), np.asarray(base.target)

    def path(t: float) -> Camera:
        e = tgt + rot_y(2.0 * math.pi * t / period_s) @ (eye - tgt)
        return Camera(eye=tuple(e), target=base.target, up=base.up, fov_y_deg=base.fov_y_deg)

    return path


def _file_camera(fc, centre, radius: float, where: str) -> Camera:
    """A file's camera (``GltfCamera``-like: kind, eye, forward, up, yfov_rad, ymag) as a :class:`Camera` whose
    target lies along its view at the depth of ``centre`` (at least a tenth of ``radius``); an orthographic
    camera becomes the perspective one that sees its half height ``ymag`` at that depth (with a warning)."""
    eye = np.asarray(fc.eye, dtype=np.float64)
    fwd = np.asarray(fc.forward, dtype=np.float64)
    depth = max(float((np.asarray(centre) - eye) @ fwd), 0.1 * max(float(radius), 1e-6))
    if getattr(fc, "kind", "perspective") == "orthographic":
        fov = 2.0 * math.degrees(math.atan(max(float(fc.ymag), 1e-9) / depth))
        fov = min(max(fov, 1.0), 120.0)
        warnings.warn(f"scene file {where!r}: its orthographic camera is shown by a pinhole camera of "
                      f"fov_y_deg {fov:.3g} (the one that sees its height at the scene's depth)", stacklevel=4)
    else:
        fov = math.degrees(float(fc.yfov_rad))
    return Camera(eye=tuple(eye), target=tuple(eye + fwd * depth), up=tuple(fc.up), fov_y_deg=fov)


def _read_scene_data(path):
    """The host description of a scene file (``foveawarp.io``'s readers: ``.gltf`` / ``.glb`` read_gltf,
    ``.obj`` read_obj, ``.xml`` read_mitsuba), errors naming the file and the extensions load_scene reads."""
    from .meshio import SCENE_FILE_EXTENSIONS

    where = str(path)
    ext = Path(path).suffix.lower()
    if ext in (".gltf", ".glb"):
        from .io.gltf import read_gltf as reader
        what = "glTF"
    elif ext in (".obj", ".xml"):
        module, fn = ("obj", "read_obj") if ext == ".obj" else ("mitsuba", "read_mitsuba")
        what = "OBJ + MTL" if ext == ".obj" else "a Mitsuba scene"
        try:
            reader = getattr(__import__(f"foveawarp.io.{module}", fromlist=[fn]), fn)
        except (ImportError, AttributeError):
            raise ValueError(f"scene file {where!r} could not be read: {what} files need foveawarp.io.{module}.{fn}, "
                             f"which this version of foveawarp does not have") from None
    else:
        raise ValueError(f"scene file {where!r} could not be read as a scene with materials: its extension {ext!r} "
                         f"is not one of ['.gltf', '.glb', '.obj', '.xml'] (load_scene reads "
                         f"{list(SCENE_FILE_EXTENSIONS)})")
    try:
        return reader(path)
    except ValueError as e:
        raise ValueError(f"scene file {where!r} could not be read as {what}: {e} (load_scene reads "
                         f"{list(SCENE_FILE_EXTENSIONS)})") from None


def scene_from_data(data, *, name: str, camera_index: Optional[int] = None, default_lights_if_none: bool = True,
                    warn_default_lights: bool = True, albedo=None, bvh_constructor: str = "auto",
                    bvh_leaf_size: Optional[int] = None) -> Scene:
    """A :class:`Scene` of a scene file's host description (``foveawarp.io.gltf.GltfScene`` or
    ``foveawarp.io.SceneData``: world-space vertices, normals, tangents, uvs, triangles, material_ids,
    materials, images, lights, cameras, and optionally colors, uvs1, environment), as the file has it:

    - materials, UVs, tangents, images and the environment carried over; ``face_albedo`` the mean base colour of
      each face (factor x texture x COLOR_0, :func:`foveawarp.scene.face_material_colors`), ``face_emission``
      its mean emission (``emissive_factor * emissive_strength`` x emissive texture); every face smooth.
    - vertex colours (COLOR_0): each face's mean colour, quantized to 8 bits, multiplies the base colour factor
      of a copy of its material (one copy per distinct colour, :func:`_bake_vertex_colours`), so the per-pixel
      base colour shows them; colour gradients within a face are not kept.
    - the camera: the file's (``camera_index`` into its cameras; None = the first), swung 8 degrees about a
      target at the scene's depth over 8 s; without one, :func:`_framing_camera` circling the scene once per 12 s.
    - lights: :func:`lights_from_file` (units stated there); when the file has no light at all (no punctual
      light, no environment, no emitting surface), :func:`default_lights` when ``default_lights_if_none`` (and a
      warning saying so when ``warn_default_lights``).
    - ``albedo`` (None, or 3 numbers in [0, 1]): the colour of the uncoloured triangles, those the file gives no
      material (glTF's default material) and no vertex colours; they become a rough dielectric (metallic 0,
      roughness 1) of that base colour. None keeps glTF's default (white, metallic 1, roughness 1).
    - objects: one static :class:`foveawarp.scene.SceneObject` per shape of the file (``data.shapes``).
    """
    path = getattr(data, "path", None)
    where = str(path) if path is not None else name
    tri = np.asarray(data.triangles)
    if tri.ndim != 2 or tri.shape[0] == 0:
        raise ValueError(f"scene file {where!r} holds no triangle mesh (no triangles in its scene)")
    materials = list(data.materials)
    fm = np.asarray(data.material_ids)
    if not materials:
        materials, fm = [default_material()], np.zeros(tri.shape[0], dtype=np.int32)
    if albedo is not None:
        materials, fm = _colour_uncoloured(materials, fm, tri, getattr(data, "colors", None),
                                           check_vec("albedo", albedo, 3, 0.0, 1.0))
    colors = getattr(data, "colors", None)
    if colors is not None:
        materials, fm = _bake_vertex_colours(materials, fm, tri, colors, where)
    images = list(data.images)
    table = MaterialTable.build(materials, len(images))
    uvs, uvs1 = data.uvs, getattr(data, "uvs1", None)
    albedo = face_material_colors(tri, fm, table, images, uvs, uvs1, slot="base_color")
    emission = face_material_colors(tri, fm, table, images, uvs, uvs1, slot="emissive")
    v = np.asarray(data.vertices, dtype=np.float64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    centre, extent = (lo + hi) / 2.0, float(np.linalg.norm(hi - lo))
    radius = max(extent / 2.0, 1e-6)
    cams = list(getattr(data, "cameras", None) or [])
    if camera_index is not None:
        if not cams or not 0 <= camera_index < len(cams):
            raise ValueError(f"camera_index must be an integer in [0, {len(cams) - 1}] ({where!r} places "
                             f"{len(cams)} camera(s)), got {camera_index}")
        fc = cams[camera_index]
    else:
        fc = getattr(data, "camera", None) or (cams[0] if cams else None)
    if fc is None:
        camera = _framing_camera(centre, radius)
        camera_path = _turntable_path(camera, 12.0)
    else:
        camera = _file_camera(fc, centre, radius, where)
        camera_path = _orbit_path(camera, 8.0, 8.0)
    lights, notes = lights_from_file(getattr(data, "lights", None), centre, extent)
    for note in notes:
        warnings.warn(f"scene file {where!r}: {note}", stacklevel=3)
    lit = bool(lights) or getattr(data, "environment", None) is not None or bool(np.asarray(emission).any())
    if not lit and default_lights_if_none:
        lights = default_lights(camera, centre, radius)
        if warn_default_lights:
            warnings.warn(f"scene file {where!r} has no point, spot or directional light: added the default lights "
                          f"(foveawarp.scenes.default_lights: a key light above right of the camera and a fill "
                          f"light at its eye)", stacklevel=3)
    return Scene(vertices=data.vertices, faces=tri, face_albedo=albedo, face_emission=emission,
                 vertex_normals=data.normals, face_smooth=np.ones(tri.shape[0], dtype=np.uint8), lights=lights,
                 camera=camera, camera_path=camera_path, name=name, bvh_constructor=bvh_constructor,
                 bvh_leaf_size=bvh_leaf_size, uvs=uvs, uvs1=uvs1 if uvs1 is not None else None,
                 tangents=data.tangents, face_material=fm, materials=table, images=images,
                 environment=getattr(data, "environment", None), objects=_shape_objects(data))


def _colour_uncoloured(materials: list, fm: np.ndarray, tri: np.ndarray, colors, albedo) -> tuple:
    """(materials, face material ids) with the triangles of glTF's default material whose vertices carry no
    colour (COLOR_0 absent or white) moved to a new rough dielectric material of base colour ``albedo``."""
    default = default_material()
    fm = np.asarray(fm, dtype=np.int32).copy()
    plain = np.isin(fm, [i for i, m in enumerate(materials) if m == default])
    if colors is not None:
        plain &= np.all(np.asarray(colors)[tri][:, :, :3] == 1.0, axis=(1, 2))
    if not plain.any():
        return materials, fm
    fm[plain] = len(materials)
    return materials + [Material(name="albedo", base_color_factor=(*albedo, 1.0), metallic_factor=0.0,
                                 roughness_factor=1.0)], fm


MAX_BAKED_MATERIALS = 4096  # distinct (material, face colour) pairs baked; beyond, faces keep their material


def _bake_vertex_colours(materials: list, fm: np.ndarray, tri: np.ndarray, colors, where: str) -> tuple:
    """(materials, face material ids) with each face's mean vertex colour (RGB, 8-bit quantized) multiplied into
    the base colour factor of a copy of its material; white faces keep theirs. Over
    :data:`MAX_BAKED_MATERIALS` distinct pairs the colours are not baked (a warning says so)."""
    from dataclasses import replace

    fm = np.asarray(fm, dtype=np.int64)
    q = np.clip(np.round(np.asarray(colors, dtype=np.float64)[tri][:, :, :3].mean(axis=1) * 255.0), 0, 255)
    q = q.astype(np.int64)
    tinted = np.any(q != 255, axis=1)
    if not tinted.any():
        return materials, fm.astype(np.int32)
    key = fm[tinted] * (256 ** 3) + (q[tinted, 0] * 256 + q[tinted, 1]) * 256 + q[tinted, 2]
    uniq, inverse = np.unique(key, return_inverse=True)
    if uniq.shape[0] > MAX_BAKED_MATERIALS:
        warnings.warn(f"scene file {where!r}: its vertex colours make {uniq.shape[0]} distinct face colours (more "
                      f"than {MAX_BAKED_MATERIALS}); they tint face_albedo only, not the per-pixel base colour",
                      stacklevel=4)
        return materials, fm.astype(np.int32)
    out = list(materials)
    for k in uniq:
        m = out[int(k // 256 ** 3)]
        c = np.array([(k // 65536) % 256, (k // 256) % 256, k % 256], dtype=np.float64) / 255.0
        bc = m.base_color_factor
        out.append(replace(m, base_color_factor=(bc[0] * c[0], bc[1] * c[1], bc[2] * c[2], bc[3])))
    fm = fm.copy()
    fm[tinted] = len(materials) + inverse.reshape(-1)
    return out, fm.astype(np.int32)


def _shape_objects(data) -> list:
    """A static SceneObject per shape of ``data`` (its name, or ``shape<i>``) that holds vertices."""
    out = []
    for i, sh in enumerate(getattr(data, "shapes", None) or []):
        a, b = (int(x) for x in sh.vertex_range)
        if b > a:
            out.append(SceneObject(sh.name or f"shape{i}", (a, b)))
    return out


def file_scene(path, name=None, camera_index: Optional[int] = None, default_lights: bool = True, albedo=None,
               bvh_constructor: str = "auto", bvh_leaf_size: Optional[int] = None) -> Scene:
    """A scene file with materials and textures as a :class:`Scene` (:func:`scene_from_data`): ``.gltf`` /
    ``.glb``, ``.obj`` with an ``.mtl`` (``foveawarp.io.obj``) or a Mitsuba ``.xml`` (``foveawarp.io.mitsuba``).
    The file is the whole scene (no ground plane is added). ``camera_index`` picks the file's camera (None: the
    first, or a framing one); ``default_lights`` adds :func:`default_lights` (with a warning) when the file has no
    light; ``albedo`` (3 numbers in [0, 1]) colours the triangles the file leaves without material and vertex
    colours."""
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"scene path must be a file path (str or os.PathLike), got {show(path)}")
    if name is not None and not isinstance(name, str):
        raise ValueError(f"name must be None or a str, got {show(name)}")
    if camera_index is not None:
        camera_index = check_int_range("camera_index", camera_index, 0)
    check_bool("default_lights", default_lights)
    check_bvh(bvh_constructor, bvh_leaf_size)
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"scene path {str(path)!r} " + ("is not a file" if p.exists() else "does not exist"))
    if albedo is not None:
        albedo = check_vec("albedo", albedo, 3, 0.0, 1.0)
    data = _read_scene_data(p)
    return scene_from_data(data, name=name or p.stem, camera_index=camera_index,
                           default_lights_if_none=default_lights, albedo=albedo, bvh_constructor=bvh_constructor,
                           bvh_leaf_size=bvh_leaf_size)


def _named_textured_scene(key: str, what: str):
    def builder(camera_index: Optional[int] = None, bvh_constructor: str = "auto",
                bvh_leaf_size: Optional[int] = None) -> Scene:
        if camera_index is not None:
            camera_index = check_int_range("camera_index", camera_index, 0)
        check_bvh(bvh_constructor, bvh_leaf_size)
        p = find_textured_scene(key)
        if p is None:
            raise ValueError(textured_scene_help(key))
        data = _read_scene_data(p)
        return scene_from_data(data, name=key, camera_index=camera_index, warn_default_lights=False,
                               bvh_constructor=bvh_constructor, bvh_leaf_size=bvh_leaf_size)

    builder.__name__ = builder.__qualname__ = key.replace("-", "_")
    builder.__doc__ = (f"{what} ({TEXTURED_SCENES[key]}, found by foveawarp.meshio.find_textured_scene), as "
                       f"foveawarp.scenes.scene_from_data makes it: framed by a camera that circles it when the "
                       f"file has none, default lights when it has none.")
    return builder


suzanne = _named_textured_scene("suzanne", "Blender's Suzanne, glTF with base colour and metallic-roughness "
                                           "textures (CC0; ships with the package)")
wicker = _named_textured_scene("wicker", "Khronos' ClearcoatWicker: a wicker-textured sphere with normal, "
                                         "occlusion and metallic-roughness maps (CC0; ships with the package)")
barrel = _named_textured_scene("barrel", "A stylized wooden barrel with normal and metallic-roughness maps "
                                         "(CC BY 4.0, Shannon Poole; shared scenes folder)")
milk_truck = _named_textured_scene("milk-truck", "Cesium's milk truck: a node hierarchy with instanced wheels "
                                                 "(CC BY 4.0, Cesium; shared scenes folder)")
grey_white_room = _named_textured_scene("grey-white-room", "The Grey & White Room by Wig42, the Mitsuba scene with "
                                                           "its camera and environment (CC BY 3.0; shared scenes "
                                                           "folder; its sky is an .exr, which the device copy "
                                                           "decodes with the openexr package)")


# ---------------------------------------------------------------------------------------------------
def mesh_on_ground(path, name=None, albedo=(0.75, 0.72, 0.68), bvh_constructor: str = "auto",
                   bvh_leaf_size: Optional[int] = None) -> Scene:
    """Any mesh file, in its own units and orientation (y up), centred on a ground plane, with a spot light
    and a camera framing it. Every mesh of the file is placed by its transform (glTF nodes, OBJ objects) and
    keeps its colour: material base colour factor times vertex colours, or face colours, averaged per face; a
    mesh without colours gets ``albedo`` (3 numbers in [0, 1]). Textures are not read."""
    if name is not None and not isinstance(name, str):
        raise ValueError(f"name must be None or a str, got {show(name)}")
    albedo = check_vec("albedo", albedo, 3, 0.0, 1.0)
    check_bvh(bvh_constructor, bvh_leaf_size)
    parts = load_mesh_parts(path)
    lo = np.min([pt.vertices.min(0) for pt in parts], axis=0)
    hi = np.max([pt.vertices.max(0) for pt in parts], axis=0)
    size = float(np.max(hi - lo))
    if not size > 0:
        raise ValueError(f"scene file {str(path)!r} has a degenerate bounding box (all vertices coincide)")
    shift = np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
    h = float(hi[1] - lo[1])
    b = SceneBuilder()
    g = 3.0 * size
    b.add_quad((-g, 0.0, -g), (0, 0, 2 * g), (2 * g, 0, 0), (0.5, 0.5, 0.52), name="ground")
    label = name or Path(path).stem
    for pt in parts:
        b.add_mesh(pt.vertices - shift, pt.faces, pt.albedo if pt.albedo is not None else albedo,
                   normals=pt.normals, smooth=pt.normals is not None,
                   name=label if len(parts) == 1 else f"{label}/{pt.name}")
    lpos = (0.6 * size, 2.5 * size, 1.2 * size)
    ldir = -np.asarray(lpos) + np.array([0.0, 0.4 * h, 0.0])
    lights = [Light(kind="spot", position=lpos, direction=tuple(ldir), cone_deg=40.0,
                    intensity=tuple(np.array([2.4, 2.3, 2.1]) * (3.0 * size) ** 2))]
    center = (0.0, 0.45 * h, 0.0)
    cam = Camera(eye=(0.0, 0.7 * h + 0.2 * size, 2.0 * size), target=center, up=(0.0, 1.0, 0.0), fov_y_deg=45.0)
    return b.build(lights=lights, camera=cam, camera_path=_orbit_path(cam, 15.0, 8.0), name=label,
                   bvh_constructor=bvh_constructor, bvh_leaf_size=bvh_leaf_size)


BUILTIN = {
    "cornell": cornell,
    "city": city,
    "eyechart": eyechart,
    "earth": earth,
    "bunny-in-box": bunny_in_box,
    "room": room,
    "suzanne": suzanne,
    "wicker": wicker,
    "barrel": barrel,
    "milk-truck": milk_truck,
    "grey-white-room": grey_white_room,
}

def with_materials(scene: Scene, roughness: Optional[float] = None) -> Scene:
    """``scene`` (an untextured scene: per-face albedo and emission) expressed in the glTF metallic-roughness
    model: one double-sided material per distinct (albedo, emission) pair, base colour the albedo, metallic 0,
    roughness ``roughness`` (None: the stand-in for the direct integrator's default Blinn-Phong lobe,
    ``foveawarp.stages.path.material_from_blinn_phong``, 0.447), the emission as ``emissive_factor`` x
    ``emissive_strength``. Geometry, normals, lights, camera, camera path and objects are shared; ``face_albedo``
    and ``face_emission`` are kept, so what reads per-face colours reads the same. The scene is then shaded by the
    textured kernels (GGX instead of Blinn-Phong; docs/pipeline.md states the difference). A scene that already
    has materials is returned as it is."""
    from .config import ShadingConfig
    from .stages.path import material_from_blinn_phong

    if not isinstance(scene, Scene):
        raise ValueError(f"scene must be a foveawarp.Scene, got {type(scene).__name__}")
    if scene.materials is not None:
        return scene
    if roughness is None:
        d = ShadingConfig()
        roughness = material_from_blinn_phong(d.specular, d.shininess)[0]
    roughness = check_range("roughness", roughness, 0.0, 1.0)
    alb = np.asarray(scene.face_albedo, np.float32)
    emi = np.asarray(scene.face_emission, np.float32)
    keys, face_material = np.unique(np.concatenate([alb, emi], axis=1), axis=0, return_inverse=True)
    mats = []
    for k, row in enumerate(keys):
        e = np.asarray(row[3:], np.float64)
        strength = float(e.max())
        factor = tuple(float(x) for x in (e / strength if strength > 0 else np.zeros(3)))
        mats.append(Material(name=f"{scene.name}-{k}", base_color_factor=(*(float(x) for x in row[:3]), 1.0),
                             metallic_factor=0.0, roughness_factor=roughness, emissive_factor=factor,
                             emissive_strength=strength, double_sided=True))
    return Scene(vertices=scene.vertices, faces=scene.faces, face_albedo=alb, face_emission=emi,
                 vertex_normals=scene.vertex_normals, face_smooth=scene.face_smooth, lights=list(scene.lights),
                 area_lights=list(scene.area_lights), camera=scene.camera, camera_path=scene.camera_path,
                 objects=list(scene.objects), name=f"{scene.name}-materials", bvh_constructor=scene.bvh_constructor,
                 bvh_leaf_size=scene.bvh_leaf_size, uvs=np.zeros((len(scene.vertices), 2), np.float32),
                 face_material=face_material.reshape(-1).astype(np.int32), materials=mats,
                 environment=scene.environment)


register_builtin_scenes(BUILTIN, mesh_on_ground, file_scene)
