"""Built-in procedural scenes, generated deterministically in code at load time (no downloads).

- ``cornell``: the classic box, two blocks, a spot light from the ceiling (indirect light, DoF, bleeding).
- ``city``: a seeded voxel city of more than 1M triangles (the large-scene performance case).
- ``eyechart``: walls of high-contrast gratings and letters at many spatial frequencies and distances.
- ``earth``: a low-poly sphere (960 triangles) with a procedural albedo.
- ``bunny-in-box``: the Cornell box with the Stanford bunny (shipped in ``assets/``) inside.

Importing this module registers ``BUILTIN`` and :func:`mesh_on_ground` with :func:`foveawarp.scene.load_scene`
(``scene`` never imports this module).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Optional

import numpy as np

from .camera import Camera
from .config import check_array, check_bool, check_finite, check_int_range, check_range, check_vec, show
from .meshio import find_named_mesh, load_mesh_arrays, load_mesh_parts, named_mesh_help
from .scene import AreaLight, Light, Scene, SceneObject, check_bvh, register_builtin_scenes

__all__ = ["SceneBuilder", "cornell", "city", "eyechart", "earth", "bunny_in_box", "mesh_on_ground", "BUILTIN"]


def rot_y(angle_rad: float) -> np.ndarray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], dtype=np.float64)


def translation(t) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = t
    return m


class SceneBuilder:
    """Accumulates triangle groups with materials, then builds a :class:`Scene`."""

    def __init__(self):
        self.v, self.f, self.alb, self.emi, self.vn, self.smooth = [], [], [], [], [], []
        self.objects = []
        self.nv = 0

    def add_mesh(self, vertices, faces, albedo, emission=(0.0, 0.0, 0.0), normals=None, smooth=False,
                 name=None, motion=None):
        """Add triangles: ``vertices`` (V, 3) finite, ``faces`` (F, 3) integers in [0, V - 1], ``albedo`` (3,) or
        (F, 3) in [0, 1], ``emission`` (3,) >= 0, ``normals`` None or (V, 3), ``smooth`` bool, ``name`` None or
        str, ``motion`` None or a callable ``t -> 4x4``."""
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
        areas.append(AreaLight(corner=(-0.25, 1.99, -0.25), edge_u=(0.0, 0.0, 0.5), edge_v=(0.5, 0.0, 0.0),
                               radiance=(6.0, 5.6, 5.0)))
    cam = Camera(eye=(0.0, 1.0, 3.4), target=(0.0, 1.0, 0.0), up=(0.0, 1.0, 0.0), fov_y_deg=45.0)
    return b, lights, areas, cam


def cornell(area_light: bool = False, motion: bool = False, bvh_constructor: str = "auto",
            bvh_leaf_size: Optional[int] = None) -> Scene:
    """Cornell box, 2 x 2 x 2 m, open at +z; red left wall, green right wall; a tall and a short block;
    a spot light under the ceiling pointing down. ``motion=True`` slides the short block."""
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
}

register_builtin_scenes(BUILTIN, mesh_on_ground)
