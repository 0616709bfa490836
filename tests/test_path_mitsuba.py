"""The path integrator against Mitsuba 3's ``path`` integrator (variant ``scalar_rgb``) on a closed diffuse room.

The room: a closed 2 x 2 x 2 m box (white floor, ceiling, back and front, red and green side walls), a box and a
flat-shaded icosphere inside, and an area light just under the ceiling facing down. The same triangles go to
Mitsuba as PLY files with ``face_normals`` (flat shading) and ``twosided`` diffuse BSDFs (foveawarp's surfaces are
two-sided); the light is a rectangle of two triangles with an ``area`` emitter and a black diffuse BSDF
(foveawarp's area lights are opaque and black). Both render with a box pixel filter: every path through a
uniform point of its pixel, so each pixel estimates the mean radiance over its area; both use Russian roulette
from depth 5.

At 2048 paths per pixel on both sides (32 x 24 pixels, 478 interior) the interior pixels' median relative error
measured 0.80 % at max_depth 2 and 0.84 % at max_depth 5, the two renderers' noise;
the 3 % bound allows about 3.5 times that. The mean ratio measured 0.9989 and 1.0009, its noise about 0.05 %, so
its 1.5 % bound tests the bias.
Interior pixels: those whose 3 x 3 neighbourhood of pixel-centre rays (cast here by brute force) meets one object,
and not the light.

The same room as a Mitsuba XML file (rectangles, a sphere, a cube, an 8-bit sRGB bitmap on the back wall, a
rectangle area emitter), read by ``foveawarp.load_scene`` into materials and textures and by Mitsuba itself: at
2048 paths per pixel the median relative error measured 0.81 % (max_depth 2) and 0.90 % (5) on 479 interior pixels,
the mean ratio 0.9989 and 1.0002; the same bounds. With the sphere a smooth dielectric (index 1.5) at max_depth 5:
1.10 % and 1.0027 over the room, 1.87 % and 1.013 over the sphere's 35 interior pixels; a GGX ``roughdielectric``
(alpha 0.2): 1.08 % and 1.0013 over the room, 3.93 % and 1.015 over the sphere.
"""

import math

import numpy as np
import pytest

import foveawarp as fw
from foveawarp.ops import render_converged

mi = pytest.importorskip("mitsuba")
trimesh = pytest.importorskip("trimesh")  # the box and the icosphere

WIDTH, HEIGHT, SPP = 32, 24, 2048
LIGHT = fw.AreaLight(corner=(-0.4, 1.98, -0.4), edge_u=(0.8, 0.0, 0.0), edge_v=(0.0, 0.0, 0.8),
                     radiance=(5.0, 4.6, 4.0))
CAMERA = fw.Camera(eye=(0.3, 1.0, 0.95), target=(-0.1, 0.8, -1.0), up=(0.0, 1.0, 0.0), fov_y_deg=60.0)


@pytest.fixture(scope="module")
def mitsuba_scalar():
    try:
        mi.set_variant("scalar_rgb")
    except (ImportError, AttributeError, ValueError) as e:  # a build without the scalar_rgb variant
        pytest.skip(f"mitsuba variant scalar_rgb unavailable: {e}")
    return mi


def _quad(c, u, v):
    c, u, v = (np.asarray(x, float) for x in (c, u, v))
    return np.stack([c, c + u, c + u + v, c + v]), np.array([[0, 1, 2], [0, 2, 3]])


def room_objects() -> list:
    """(name, vertices, faces, albedo) of every object of the room, the light excluded."""
    white, red, green = (0.7, 0.7, 0.7), (0.7, 0.15, 0.1), (0.15, 0.6, 0.15)
    objs = [("floor", *_quad((-1, 0, -1), (0, 0, 2), (2, 0, 0)), white),
            ("ceiling", *_quad((-1, 2, -1), (2, 0, 0), (0, 0, 2)), white),
            ("back", *_quad((-1, 0, -1), (2, 0, 0), (0, 2, 0)), white),
            ("front", *_quad((-1, 0, 1), (0, 2, 0), (2, 0, 0)), white),
            ("left", *_quad((-1, 0, -1), (0, 2, 0), (0, 0, 2)), red),
            ("right", *_quad((1, 0, -1), (0, 0, 2), (0, 2, 0)), green)]
    b = trimesh.creation.box(extents=(0.6, 0.9, 0.6))
    b.apply_transform(trimesh.transformations.rotation_matrix(math.radians(20), (0, 1, 0)))
    b.apply_translation((-0.25, 0.45, -0.4))
    objs.append(("block", np.asarray(b.vertices), np.asarray(b.faces), (0.6, 0.6, 0.5)))
    s = trimesh.creation.icosphere(subdivisions=1, radius=0.3)
    s.apply_translation((0.45, 0.3, -0.3))
    objs.append(("ball", np.asarray(s.vertices), np.asarray(s.faces), (0.3, 0.4, 0.7)))
    return objs


def foveawarp_scene(objs) -> fw.Scene:
    verts, faces, albedo, off = [], [], [], 0
    for _, v, f, a in objs:
        verts.append(v)
        faces.append(f + off)
        albedo.append(np.tile(a, (len(f), 1)))
        off += len(v)
    return fw.Scene(vertices=np.concatenate(verts), faces=np.concatenate(faces), face_albedo=np.concatenate(albedo),
                    area_lights=[LIGHT])


def _write_ply(path, v, f):
    with open(path, "w") as fh:
        fh.write(f"ply\nformat ascii 1.0\nelement vertex {len(v)}\nproperty float x\nproperty float y\n"
                 f"property float z\nelement face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n")
        for p in v:
            fh.write(f"{p[0]:.9g} {p[1]:.9g} {p[2]:.9g}\n")
        for t in f:
            fh.write(f"3 {t[0]} {t[1]} {t[2]}\n")


def mitsuba_scene(m, objs, tmp_path, max_depth: int):
    d = {"type": "scene", "integrator": {"type": "path", "max_depth": max_depth, "rr_depth": 5},
         "sensor": {"type": "perspective", "fov": CAMERA.fov_y_deg, "fov_axis": "y",
                    "to_world": m.ScalarTransform4f().look_at(origin=list(CAMERA.eye), target=list(CAMERA.target),
                                                              up=list(CAMERA.up)),
                    "film": {"type": "hdrfilm", "width": WIDTH, "height": HEIGHT, "rfilter": {"type": "box"},
                             "pixel_format": "rgb"},
                    "sampler": {"type": "independent", "sample_count": SPP}}}
    for name, v, f, a in objs:
        p = tmp_path / f"{name}.ply"
        _write_ply(p, v, f)
        d[name] = {"type": "ply", "filename": str(p), "face_normals": True,
                   "bsdf": {"type": "twosided", "bsdf": {"type": "diffuse",
                                                         "reflectance": {"type": "rgb", "value": list(a)}}}}
    lv, lf = _quad(LIGHT.corner, LIGHT.edge_u, LIGHT.edge_v)  # winding: normal cross(edge_u, edge_v), facing down
    _write_ply(tmp_path / "light.ply", lv, lf)
    d["light"] = {"type": "ply", "filename": str(tmp_path / "light.ply"), "face_normals": True,
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}},
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": list(LIGHT.radiance)}}}
    return m.load_dict(d)


def first_hits(verts, faces, o, d) -> np.ndarray:
    """Index of the nearest triangle each ray (o, d[k]) meets, -1 for none: brute-force Moller-Trumbore."""
    p0, p1, p2 = (verts[faces[:, k]] for k in range(3))
    e1, e2 = p1 - p0, p2 - p0
    pv = np.cross(d[:, None, :], e2[None])  # (R, T, 3)
    det = (pv * e1[None]).sum(-1)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tv = o - p0  # (T, 3)
    u = (pv * tv[None]).sum(-1) * inv
    qv = np.cross(tv, e1)  # (T, 3)
    v = (d @ qv.T) * inv
    t = (qv * e2).sum(-1)[None] * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9)
    t = np.where(hit, t, np.inf)
    best = t.argmin(axis=1)
    return np.where(np.isfinite(t[np.arange(len(d)), best]), best, -1)


def interior_mask(objs) -> np.ndarray:
    """(H, W) bool: the pixel-centre rays of the pixel and its 8 neighbours meet the same object, not the light."""
    meshes = [(v, f) for _, v, f, _ in objs] + [_quad(LIGHT.corner, LIGHT.edge_u, LIGHT.edge_v)]
    label = np.concatenate([np.full(len(f), i) for i, (_, f) in enumerate(meshes)])
    off = np.cumsum([0] + [len(v) for v, _ in meshes])[:-1]
    verts = np.concatenate([v for v, _ in meshes])
    faces = np.concatenate([f + o for (_, f), o in zip(meshes, off)])
    e = np.asarray(CAMERA.eye, float)
    fwd = np.asarray(CAMERA.target, float) - e
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, CAMERA.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    t = math.tan(math.radians(CAMERA.fov_y_deg) / 2)
    x, y = np.meshgrid(np.arange(WIDTH) + 0.5, np.arange(HEIGHT) + 0.5)
    d = fwd + ((2 * x / WIDTH - 1) * t * WIDTH / HEIGHT)[..., None] * right + ((1 - 2 * y / HEIGHT) * t)[..., None] * up
    d = (d / np.linalg.norm(d, axis=-1, keepdims=True)).reshape(-1, 3)
    tri = first_hits(verts, faces, e, d)
    obj = np.where(tri >= 0, label[tri], -1).reshape(HEIGHT, WIDTH)
    light = len(meshes) - 1
    ok = np.zeros_like(obj, dtype=bool)
    for j in range(1, HEIGHT - 1):
        for i in range(1, WIDTH - 1):
            n = obj[j - 1:j + 2, i - 1:i + 2]
            ok[j, i] = obj[j, i] >= 0 and obj[j, i] != light and np.all(n == obj[j, i])
    return ok


def check_against_mitsuba(ours, ref, mask) -> None:
    """The bounds on the interior pixels (``mask``, over 40 % of the image): median relative error of the
    luminance <= 3 %, mean ratio within 1.5 %, and per channel (the red and green walls' light) within 1.5 %."""
    assert mask.sum() > 0.4 * mask.size
    lo, lr = ours.mean(-1)[mask], ref.mean(-1)[mask]
    assert lr.min() > 0.0
    rel = np.abs(lo / lr - 1.0)
    ratio = lo.mean() / lr.mean()
    assert np.median(rel) <= 0.03, (np.median(rel), ratio)
    assert abs(ratio - 1.0) <= 0.015, ratio
    np.testing.assert_allclose(ours[mask].mean(0) / ref[mask].mean(0), 1.0, atol=0.015)


@pytest.mark.parametrize("max_depth", [2, 5])
def test_closed_room_matches_mitsuba_path(mitsuba_scalar, tmp_path, max_depth):
    m = mitsuba_scalar
    objs = room_objects()
    ref = np.array(m.render(mitsuba_scene(m, objs, tmp_path, max_depth), seed=max_depth), dtype=np.float64)[..., :3]
    ours = render_converged(foveawarp_scene(objs), CAMERA, WIDTH, HEIGHT, SPP, max_depth=max_depth, rr_depth=5,
                            seed=3, device="cpu", pixel_filter="box",
                            shading=fw.ShadingConfig(specular=0.0)).astype(np.float64)
    check_against_mitsuba(ours, ref, interior_mask(objs))



# ---------------------------------------------------------------------------------------------------------------
# a Mitsuba XML scene loaded by both renderers

def xml_room(tmp_path, max_depth: int, glass: str = "") -> str:
    """The closed room as a Mitsuba 3 XML file: rectangles for the walls (two-sided diffuse, the back wall with an
    8-bit sRGB bitmap), a sphere, a cube, and a rectangle area emitter (single-sided, black diffuse) under the
    ceiling facing down; the sensor's fov along x (Mitsuba's default axis). ``glass`` "smooth": the sphere is a
    smooth dielectric of index 1.5 instead of a diffuse; "rough": a GGX rough dielectric of alpha 0.2."""
    from test_mitsuba_xml import _png

    yy, xx = np.mgrid[0:8, 0:8]
    img = np.zeros((8, 8, 4), np.uint8)
    img[..., 0] = np.where((xx + yy) % 2 == 0, 220, 40)  # a checker, red growing to the right, green downwards
    img[..., 1] = 60 + 20 * yy
    img[..., 2] = 30 + 25 * xx
    img[..., 3] = 255
    _png(tmp_path / "checker.png", img)

    def diffuse(rgb, two=True):
        b = f'<bsdf type="diffuse"><rgb name="reflectance" value="{rgb}"/></bsdf>'
        return f'<bsdf type="twosided">{b}</bsdf>' if two else b

    def rect(name, ops, bsdf):
        return f'<shape type="rectangle" id="{name}"><transform name="to_world">{ops}</transform>{bsdf}</shape>'

    white = diffuse("0.7, 0.7, 0.7")
    checker = ('<bsdf type="twosided"><bsdf type="diffuse"><texture name="reflectance" type="bitmap">'
               '<string name="filename" value="checker.png"/></texture></bsdf></bsdf>')
    e, t = CAMERA.eye, CAMERA.target
    body = (
        f'<integrator type="path"><integer name="max_depth" value="{max_depth}"/>'
        f'<integer name="rr_depth" value="5"/></integrator>'
        f'<sensor type="perspective"><float name="fov" value="70"/><transform name="to_world">'
        f'<lookat origin="{e[0]}, {e[1]}, {e[2]}" target="{t[0]}, {t[1]}, {t[2]}" up="0, 1, 0"/></transform>'
        f'<sampler type="independent"><integer name="sample_count" value="{SPP}"/></sampler>'
        f'<film type="hdrfilm"><integer name="width" value="{WIDTH}"/><integer name="height" value="{HEIGHT}"/>'
        f'<rfilter type="box"/><string name="pixel_format" value="rgb"/></film></sensor>'
        + rect("floor", '<rotate x="1" angle="-90"/>', white)
        + rect("ceiling", '<rotate x="1" angle="90"/><translate y="2"/>', white)
        + rect("back", '<translate y="1" z="-1"/>', checker)
        + rect("front", '<rotate y="1" angle="180"/><translate y="1" z="1"/>', white)
        + rect("left", '<rotate y="1" angle="90"/><translate x="-1" y="1"/>', diffuse("0.7, 0.15, 0.1"))
        + rect("right", '<rotate y="1" angle="-90"/><translate x="1" y="1"/>', diffuse("0.15, 0.6, 0.15"))
        + '<shape type="sphere" id="ball"><point name="center" x="0.45" y="0.3" z="-0.3"/>'
          '<float name="radius" value="0.3"/>'
        + {"smooth": '<bsdf type="dielectric"><float name="int_ior" value="1.5"/></bsdf>',
           "rough": '<bsdf type="roughdielectric"><string name="distribution" value="ggx"/>'
                    '<float name="alpha" value="0.2"/><float name="int_ior" value="1.5"/></bsdf>',
           "": diffuse("0.3, 0.4, 0.7", two=False)}[glass] + '</shape>'
        + '<shape type="cube" id="block"><transform name="to_world"><scale x="0.3" y="0.45" z="0.3"/>'
          '<rotate y="1" angle="20"/><translate x="-0.25" y="0.45" z="-0.4"/></transform>'
          + diffuse("0.6, 0.6, 0.5") + '</shape>'
        + '<shape type="rectangle" id="light"><transform name="to_world"><scale value="0.4"/>'
          '<rotate x="1" angle="90"/><translate y="1.98"/></transform>'
          '<bsdf type="diffuse"><rgb name="reflectance" value="0, 0, 0"/></bsdf>'
          '<emitter type="area"><rgb name="radiance" value="5, 4.6, 4"/></emitter></shape>')
    p = tmp_path / f"room{max_depth}{'-' + glass if glass else ''}.xml"
    p.write_text(f'<?xml version="1.0"?>\n<scene version="3.0.0">\n{body}\n</scene>\n')
    return str(p)


def mitsuba_interior(m, scene, shape=None) -> np.ndarray:
    """(H, W) bool from Mitsuba's own pixel-centre rays: the pixel and its 8 neighbours see the same shape, not
    the light (``shape``: that shape only)."""
    sensor = scene.sensors()[0]
    ids = np.full((HEIGHT, WIDTH), "", dtype=object)
    for y in range(HEIGHT):
        for x in range(WIDTH):
            ray, _ = sensor.sample_ray(0.0, 0.5, m.Point2f((x + 0.5) / WIDTH, (y + 0.5) / HEIGHT),
                                       m.Point2f(0.5, 0.5))
            si = scene.ray_intersect(ray)
            ids[y, x] = si.shape.id() if si.is_valid() else ""
    ok = np.zeros((HEIGHT, WIDTH), dtype=bool)
    for j in range(1, HEIGHT - 1):
        for i in range(1, WIDTH - 1):
            ok[j, i] = ids[j, i] not in ("", "light") and np.all(ids[j - 1:j + 2, i - 1:i + 2] == ids[j, i])
    return ok if shape is None else ok & (ids == shape)


@pytest.mark.parametrize("max_depth, glass", [(2, ""), (5, ""), (5, "smooth"), (5, "rough")])
def test_xml_room_matches_mitsuba_path(mitsuba_scalar, tmp_path, max_depth, glass):
    """The XML room read by foveawarp.load_scene (materials, a bitmap texture, the emitter as an emissive
    single-sided material; with ``glass`` a smooth or rough dielectric sphere, refracting) and by Mitsuba: the
    same bounds as the closed room above. foveawarp's texture LOD is "none" (Mitsuba's bitmap has no MIP maps)
    and its diffuse materials' specular scale 0 (Mitsuba's diffuse is Lambert; the glTF model's dielectric lobe
    would add 4 %)."""
    import warnings

    from foveawarp.scene import DeviceScene
    from foveawarp.surface import set_material_specular

    m = mitsuba_scalar
    path = xml_room(tmp_path, max_depth, glass)
    mscene = m.load_file(path)
    ref = np.array(m.render(mscene, seed=max_depth), dtype=np.float64)[..., :3]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = fw.load_scene(path)
    # everything in the file is supported: no warning, but the glass's note on the direct integrator
    assert [str(x.message) for x in caught if "dielectric" not in str(x.message)] == []
    assert len(caught) == int(bool(glass))
    assert scene.materials is not None and len(scene.images) == 1
    ds = DeviceScene(scene, device="cpu")
    set_material_specular(ds, 0.0)
    ours = render_converged(ds, scene.camera, WIDTH, HEIGHT, SPP, max_depth=max_depth, rr_depth=5, seed=5,
                            device="cpu", pixel_filter="box",
                            shading=fw.ShadingConfig(texture_lod="none")).astype(np.float64)
    check_against_mitsuba(ours, ref, mitsuba_interior(m, mscene))
    if glass:
        # the scene seen through the sphere (35 interior pixels): median 1.87 % and mean ratio 1.013 measured for the
        # smooth sphere, 3.93 % and 1.015 for the rough one (GGX, alpha 0.2: Mitsuba's separable Smith term against
        # the height-correlated one here, and its blurred caustics the noisiest paths); 5 % and 3 % bounds (a
        # sphere that does not bend the rays already moves the whole room's mean ratio to 1.0495)
        ball = mitsuba_interior(m, mscene, "ball")
        assert ball.sum() >= 20
        rb = np.abs(ours.mean(-1)[ball] / ref.mean(-1)[ball] - 1.0)
        assert np.median(rb) <= 0.05 and abs(ours[ball].mean() / ref[ball].mean() - 1.0) <= 0.03, (
            np.median(rb), ours[ball].mean() / ref[ball].mean())
