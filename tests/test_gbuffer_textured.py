"""The textured G-buffer (kernels/gbuffer_textured.py, kernels/surface.py) against a NumPy reference.

The reference intersects the pixel-centre rays with trimesh, interpolates the UVs with trimesh's barycentrics and
samples the textures with the NumPy sampler of tests/test_texture.py; normal maps are applied in a tangent frame
built here from the UVs. Tolerances: 2e-5 on float32 albedo and normals, 1e-3 on the half-precision roughness
and metallic (float16 has an 11-bit significand: 4.9e-4 at 1).
"""

import numpy as np
import pytest
import trimesh
import warp as wp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from foveawarp.buffers import GBuffer
from foveawarp.camera import Camera
from foveawarp.config import Config
from foveawarp.frame_loop import FrameLoop
from foveawarp.materials import Material, TextureRef
from foveawarp.scene import DeviceScene, Light, Scene
from foveawarp.stages.gbuffer import GBufferStage
from test_texture import ref_bilinear, ref_mip_chain, ref_trilinear

W, H = 48, 40
CAM = Camera(eye=(0.0, 0.0, 3.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_y_deg=45.0)


def quad(z=0.0, x0=-1.0, x1=1.0, y0=-1.0, y1=1.0, mirror_u=False, back=False):
    """A quad in the plane z facing +z (the camera) unless ``back``, glTF UVs: (0, 0) at its top-left corner."""
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], np.float32)
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32)
    if mirror_u:
        uv[:, 0] = 1.0 - uv[:, 0]
    f = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    if back:
        f = f[:, ::-1].copy()
    return v, uv, f


def make_scene(quads, materials, images, face_mat=None, tangents=None, smooth=False):
    vs, uvs, fs = [], [], []
    n = 0
    for v, uv, f in quads:
        vs.append(v)
        uvs.append(uv)
        fs.append(f + n)
        n += len(v)
    v, uv, f = np.concatenate(vs), np.concatenate(uvs), np.concatenate(fs)
    fm = np.zeros(len(f), np.int32) if face_mat is None else np.asarray(face_mat, np.int32)
    vn = None
    if smooth:
        vn = np.tile(np.array([[0.0, 0.0, 1.0]], np.float32), (len(v), 1))
    return Scene(v, f, None, uvs=uv, face_material=fm, materials=materials, images=images, tangents=tangents,
                 vertex_normals=vn, face_smooth=np.full(len(f), int(smooth), np.uint8),
                 lights=[Light(position=(0.0, 0.0, 3.0))])


def gbuffer_of(scene, device, lod="none", w=W, h=H, cam=CAM):
    ds = DeviceScene(scene, device)
    g = GBuffer(w, h, device)
    st_ = GBufferStage(ds, w, h, device)
    st_.texture_lod = lod
    st_.run(g, cam, cam)
    return g


def pixel_rays(cam, w=W, h=H):
    r, u, f = (np.asarray(a, np.float64) for a in cam._basis_floats())
    ys, xs = np.mgrid[0:h, 0:w]
    sx = (2.0 * (xs + 0.5) / w - 1.0) * cam.tan_half_fov_y * (w / h)
    sy = (1.0 - 2.0 * (ys + 0.5) / h) * cam.tan_half_fov_y
    d = f[None, None] + sx[..., None] * r + sy[..., None] * u
    d /= np.linalg.norm(d, axis=2, keepdims=True)
    return np.broadcast_to(np.asarray(cam.eye, np.float64), d.shape).reshape(-1, 3), d.reshape(-1, 3)


def ref_hits(scene, cam, w=W, h=H):
    """(hit mask (H*W,), face (H*W,), barycentric weights of the face's 3 vertices (H*W, 3)) of the closest hit:
    brute-force Moller-Trumbore over every triangle in float64, weights by trimesh."""
    o, d = pixel_rays(cam, w, h)
    tris = scene.vertices.astype(np.float64)[scene.faces]
    e1, e2 = tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    pv = np.cross(d[:, None], e2[None])
    det = np.einsum("fk,nfk->nf", e1, pv)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tv = o[:, None] - tris[None, :, 0]
    a = np.einsum("nfk,nfk->nf", tv, pv) * inv
    qv = np.cross(tv, e1[None])
    b = np.einsum("nk,nfk->nf", d, qv) * inv
    t = np.einsum("fk,nfk->nf", e2, qv) * inv
    valid = ok & (a >= 0) & (b >= 0) & (a + b <= 1) & (t > 0)
    t = np.where(valid, t, np.inf)
    face = np.argmin(t, axis=1)
    hit = np.isfinite(t[np.arange(len(o)), face])
    face = np.where(hit, face, -1)
    bary = np.zeros((len(o), 3))
    loc = o[hit] + d[hit] * t[np.flatnonzero(hit), face[hit]][:, None]
    bary[hit] = trimesh.triangles.points_to_barycentric(tris[face[hit]], loc)
    return hit, face, bary


def rgba(img):
    img = np.asarray(img, np.float32)
    out = np.ones(img.shape[:2] + (4,), np.float32)
    out[..., :img.shape[2]] = img
    return out


def test_albedo_normal_roughness_match_numpy_reference(device):
    rng = np.random.default_rng(3)
    base = rng.uniform(0.05, 1.0, (8, 12, 3)).astype(np.float32)
    mr = rng.uniform(0.0, 1.0, (6, 5, 3)).astype(np.float32)
    nmap = np.stack([rng.uniform(0.3, 0.7, (4, 4)), rng.uniform(0.3, 0.7, (4, 4)), np.full((4, 4), 0.9)],
                    axis=2).astype(np.float32)
    m = Material(base_color_factor=(0.9, 0.6, 0.8, 1.0), base_color_texture=TextureRef(0, color_space="srgb"),
                 metallic_factor=0.7, roughness_factor=0.9, metallic_roughness_texture=TextureRef(1),
                 normal_texture=TextureRef(2), normal_scale=0.8)
    v, uv, f = quad(x0=-1.2, x1=1.0, y0=-0.9, y1=1.1)
    tangents = np.tile(np.array([[1.0, 0.0, 0.0, 1.0]], np.float32), (4, 1))
    sc = make_scene([(v, uv, f)], [m], [base, mr, nmap], tangents=tangents)
    g = gbuffer_of(sc, device).numpy()
    hit, face, bary = ref_hits(sc, CAM)
    assert np.array_equal(g["hit"].reshape(-1) != 0, hit)
    uvh = np.einsum("nk,nkc->nc", bary[hit], uv[sc.faces[face[hit]]].astype(np.float64))
    alb = ref_bilinear(rgba(base), uvh, "repeat", "repeat")[:, :3] * (0.9, 0.6, 0.8)
    np.testing.assert_allclose(g["albedo"].reshape(-1, 3)[hit], alb, atol=2e-5)
    t = ref_bilinear(rgba(mr), uvh, "repeat", "repeat")
    np.testing.assert_allclose(g["roughness"].reshape(-1)[hit], 0.9 * t[:, 1], atol=1e-3)
    np.testing.assert_allclose(g["metallic"].reshape(-1)[hit], 0.7 * t[:, 2], atol=1e-3)
    # tangent +x, bitangent +y (the image's top), normal +z
    nt = ref_bilinear(rgba(nmap), uvh, "repeat", "repeat")[:, :3] * 2.0 - 1.0
    n = np.stack([nt[:, 0] * 0.8, nt[:, 1] * 0.8, nt[:, 2]], axis=1)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    np.testing.assert_allclose(g["normal"].reshape(-1, 3)[hit], n, atol=2e-5)
    assert np.all(g["albedo"].reshape(-1, 3)[~hit] == 0.0)


def test_uv_orientation_known_pattern(device):
    # quadrants: top-left red, top-right green, bottom-left blue, bottom-right white (row 0 = the image's top)
    img = np.zeros((2, 2, 3), np.float32)
    img[0, 0], img[0, 1], img[1, 0], img[1, 1] = (1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 1)
    m = Material(base_color_texture=TextureRef(0, filter="nearest", color_space="srgb"), metallic_factor=0.0)
    sc = make_scene([quad()], [m], [img])
    a = gbuffer_of(sc, device).albedo.numpy()
    cy, cx = H // 2, W // 2
    np.testing.assert_array_equal(a[cy - 5, cx - 5], (1, 0, 0))
    np.testing.assert_array_equal(a[cy - 5, cx + 5], (0, 1, 0))
    np.testing.assert_array_equal(a[cy + 5, cx - 5], (0, 0, 1))
    np.testing.assert_array_equal(a[cy + 5, cx + 5], (1, 1, 1))


@pytest.mark.parametrize("with_tangents", [False, True])
def test_tangent_frame_on_mirrored_uvs(device, with_tangents):
    # a map that tilts the normal towards +u: on the mirrored quad +u runs to -x, so the tilt flips
    nmap = np.array([[[0.9, 0.5, 0.6]]], np.float32)
    m = Material(normal_texture=TextureRef(0), metallic_factor=0.0)
    left = quad(x0=-1.5, x1=-0.1)
    right = quad(x0=0.1, x1=1.5, mirror_u=True)
    tangents = None
    if with_tangents:  # as a reader computes them: dP/du with the handedness of each UV triangle
        tangents = np.array([[1, 0, 0, 1]] * 4 + [[-1, 0, 0, -1]] * 4, np.float32)
    sc = make_scene([left, right], [m], [nmap], tangents=tangents)
    n = gbuffer_of(sc, device).normal.numpy()
    x = np.array([0.8, 0.0, 0.2])
    x /= np.linalg.norm(x)
    np.testing.assert_allclose(n[H // 2, W // 4], x, atol=2e-5)
    np.testing.assert_allclose(n[H // 2, 3 * W // 4], x * (-1, 1, 1), atol=2e-5)
    # the bitangent keeps pointing to the image's top on both (y up): a +v tilt gives +y on both
    nmap2 = np.array([[[0.5, 0.9, 0.6]]], np.float32)
    sc2 = make_scene([left, right], [m], [nmap2], tangents=tangents)
    n2 = gbuffer_of(sc2, device).normal.numpy()
    assert n2[H // 2, W // 4][1] > 0.7 and n2[H // 2, 3 * W // 4][1] > 0.7


@pytest.mark.parametrize("mode", ["MASK", "BLEND"])
def test_cutouts_show_what_is_behind(device, mode):
    alpha = np.ones((1, 2, 4), np.float32)
    alpha[0, 0, 3] = 0.3  # the left half below both cutoffs (0.4 and BLEND's 0.5)
    front = Material(base_color_factor=(1.0, 0.0, 0.0, 1.0),
                     base_color_texture=TextureRef(0, filter="nearest", color_space="srgb"),
                     alpha_mode=mode, alpha_cutoff=0.4, double_sided=True)
    back = Material(base_color_factor=(0.0, 0.0, 1.0, 1.0))
    sc = make_scene([quad(z=0.5), quad(z=-0.5, x0=-3, x1=3, y0=-3, y1=3)], [front, back], [alpha],
                    face_mat=[0, 0, 1, 1])
    g = gbuffer_of(sc, device).numpy()
    cy = H // 2
    np.testing.assert_array_equal(g["albedo"][cy, W // 2 - 4], (0, 0, 1))  # through the cut-out
    np.testing.assert_array_equal(g["albedo"][cy, W // 2 + 4], (1, 0, 0))
    o, d = pixel_rays(CAM)
    d = d.reshape(H, W, 3)
    np.testing.assert_allclose(g["depth"][cy, W // 2 - 4], 3.5 / abs(d[cy, W // 2 - 4, 2]), rtol=1e-5)
    np.testing.assert_allclose(g["depth"][cy, W // 2 + 4], 2.5 / abs(d[cy, W // 2 + 4, 2]), rtol=1e-5)


@pytest.mark.parametrize("double_sided", [False, True])
def test_single_sided_back_faces_are_culled(device, double_sided):
    front = Material(base_color_factor=(1.0, 0.0, 0.0, 1.0), double_sided=double_sided)
    wall = Material(base_color_factor=(0.0, 1.0, 0.0, 1.0))
    sc = make_scene([quad(z=0.5, back=True), quad(z=-0.5, x0=-3, x1=3, y0=-3, y1=3)], [front, wall], [],
                    face_mat=[0, 0, 1, 1])
    g = gbuffer_of(sc, device).numpy()
    c = g["albedo"][H // 2, W // 2]
    np.testing.assert_array_equal(c, (1, 0, 0) if double_sided else (0, 1, 0))
    if double_sided:  # the back face's normal is turned to the viewer
        np.testing.assert_allclose(g["normal"][H // 2, W // 2], (0, 0, 1), atol=1e-6)


def test_ray_cone_lod_filters_a_fine_checker(device):
    k = np.indices((64, 64)).sum(axis=0) % 2
    img = np.repeat(k[..., None], 3, axis=2).astype(np.float32)
    m = Material(base_color_texture=TextureRef(0, color_space="srgb"), metallic_factor=0.0)
    v, uv, f = quad()
    sc = make_scene([(v, uv * 8.0, f)], [m], [img])  # 512 texels across ~30 pixels: ~17 texels a pixel
    none = gbuffer_of(sc, device, "none").numpy()
    cone = gbuffer_of(sc, device, "ray_cone").numpy()
    hit = none["hit"] != 0
    a0, a1 = none["albedo"][hit][:, 0], cone["albedo"][hit][:, 0]
    assert a0.std() > 0.1  # level 0 aliases
    assert a1.std() < 0.02 and abs(a1.mean() - 0.5) < 0.02  # the cone's level averages the checker
    # one pixel against the formula: lambda = Delta + log2(W / |n.d|), sampled trilinearly by the reference
    hitm, face, bary = ref_hits(sc, CAM)
    i = np.flatnonzero(hitm)[len(np.flatnonzero(hitm)) // 2]
    y, x = divmod(i, W)
    o, d = pixel_rays(CAM)
    t = 3.0 / abs(d[i, 2])
    alpha = np.arctan(2.0 * CAM.tan_half_fov_y / H)
    p_area = 2.0 * 2.0 / 2.0
    t_area = 8.0 * 8.0 / 2.0
    lam = 0.5 * np.log2(64 * 64 * t_area / p_area) + np.log2(2.0 * t * np.tan(alpha / 2) / abs(d[i, 2]))
    uvh = bary[i] @ (uv[sc.faces[face[i]] % 4].astype(np.float64) * 8.0)
    ref = ref_trilinear(ref_mip_chain(rgba(img)), uvh[None], [lam], "repeat", "repeat")[0, :3]
    np.testing.assert_allclose(cone["albedo"][y, x], ref, atol=1e-4)


def test_sparse_mode_reads_the_same_surface(device):
    rng = np.random.default_rng(5)
    img = rng.uniform(0.0, 1.0, (16, 16, 3)).astype(np.float32)
    m = Material(base_color_texture=TextureRef(0, color_space="srgb"), metallic_factor=0.0, roughness_factor=0.6)
    sc = make_scene([quad()], [m], [img])
    cfg = Config().with_(foveation={"gbuffer": "sparse"}, shading={"texture_lod": "none"})
    full = FrameLoop(sc, width=W, height=H, config=Config().with_(shading={"texture_lod": "none"}), device=device)
    sparse = FrameLoop(sc, width=W, height=H, config=cfg, device=device)
    f0 = full.render(CAM)
    g0 = f0.gbuffer.numpy()
    f1 = sparse.render(CAM)
    g1 = f1.gbuffer.numpy()
    s = f1.sampling_map.numpy() != 0
    assert s.sum() > 50
    for k in ("albedo", "normal", "roughness", "metallic", "depth", "hit"):
        np.testing.assert_array_equal(g1[k][s], g0[k][s], err_msg=k)
    # with texture_lod "none" the radiance of a sampled pixel is the full mode's reference value
    ref = full.render_reference(CAM).numpy()
    im = f1.numpy()
    np.testing.assert_allclose(im[s], ref[s], atol=1e-6)


def test_untextured_scene_keeps_its_gbuffer(device):
    v, uv, f = quad()
    sc = Scene(v, f, np.array([0.5, 0.25, 0.125], np.float32), lights=[Light(position=(0, 0, 3))])
    g = gbuffer_of(sc, device)
    assert not g.textured and g.material is None
    np.testing.assert_array_equal(np.unique(g.roughness.numpy()), [1.0])
    np.testing.assert_array_equal(np.unique(g.metallic.numpy()), [0.0])
    a = g.albedo.numpy()
    np.testing.assert_array_equal(a[H // 2, W // 2], (0.5, 0.25, 0.125))


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(uv_scale=st.sampled_from([0.0, 1e-30, 1.0, 1e6, 3e7]), collapse=st.sampled_from([None, 0, 1, 2]),
       lod=st.sampled_from(["none", "ray_cone"]), nscale=st.sampled_from([0.0, 1.0, -50.0, 1e6]))
def test_degenerate_uvs_and_faces_give_finite_values(uv_scale, collapse, lod, nscale):
    v, uv, f = quad()
    v = v.copy()
    if collapse is not None:  # a zero-area face: its vertices on a line or a point
        v[f[0, collapse]] = v[f[0, (collapse + 1) % 3]]
    rng = np.random.default_rng(1)
    base = rng.uniform(0, 1, (3, 5, 4)).astype(np.float32)
    nmap = rng.uniform(0, 1, (2, 3, 3)).astype(np.float32)
    m = Material(base_color_texture=TextureRef(0, color_space="srgb"), normal_texture=TextureRef(1),
                 normal_scale=nscale,
                 metallic_roughness_texture=TextureRef(0), occlusion_texture=TextureRef(1),
                 emissive_texture=TextureRef(0, color_space="srgb"), emissive_factor=(1, 1, 1), alpha_mode="MASK")
    sc = make_scene([(v, uv * np.float32(uv_scale), f)], [m], [base, nmap], smooth=True)
    g = gbuffer_of(sc, "cpu", lod, w=16, h=12)
    for k, a in g.numpy().items():
        assert np.all(np.isfinite(a.astype(np.float64))), k
    assert np.all(np.isfinite(g.material.numpy().astype(np.float64)))
    assert np.all(np.isfinite(g.emission.numpy()))
    n = g.normal.numpy()[g.hit.numpy() != 0]
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-5)


@pytest.mark.parametrize("gbuffer", ["full", "sparse"])
def test_saliency_sees_the_texture(device, gbuffer):
    # one face material, a texture of two colours split down the middle: only the texture gives an albedo edge
    img = np.zeros((1, 2, 3), np.float32)
    img[0, 0], img[0, 1] = (0.9, 0.9, 0.9), (0.05, 0.05, 0.05)
    m = Material(base_color_texture=TextureRef(0, filter="nearest", color_space="srgb"), metallic_factor=0.0)
    sc = make_scene([quad(x0=-3, x1=3, y0=-3, y1=3)], [m], [img])
    cfg = Config().with_(foveation={"gbuffer": gbuffer, "fovea_deg": 0.0}, saliency={"use_normal": False},
                         shading={"texture_lod": "none"})
    loop = FrameLoop(sc, width=W, height=H, config=cfg, device=device)
    loop.render(CAM, gaze_px=(2.0, 2.0))
    sal = loop.sampling.saliency.numpy()
    prob = loop.sampling.probability.numpy()
    edge = sal[:, W // 2 - 4:W // 2 + 4]
    assert np.all(edge.max(axis=1) >= 0.99)  # the texture's edge is salient on every row
    # away from the edge the saliency is the eccentricity probability alone
    far = np.r_[0:W // 2 - 8, W // 2 + 8:W]
    np.testing.assert_allclose(sal[:, far][prob[:, far] < 0.9], prob[:, far][prob[:, far] < 0.9], atol=1e-6)
