"""Camera: projection round trips and matrices against independent NumPy formulas."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import foveawarp as fw

finite = st.floats(-50, 50, allow_nan=False)


def _lookat_np(eye, target, up):
    # independent Gram-Schmidt construction of the camera frame
    f = np.asarray(target, float) - np.asarray(eye, float)
    f = f / np.sqrt((f * f).sum())
    upv = np.asarray(up, float)
    r = np.array([f[1] * upv[2] - f[2] * upv[1], f[2] * upv[0] - f[0] * upv[2], f[0] * upv[1] - f[1] * upv[0]])
    r = r / np.sqrt((r * r).sum())
    u = np.array([r[1] * f[2] - r[2] * f[1], r[2] * f[0] - r[0] * f[2], r[0] * f[1] - r[1] * f[0]])
    return r, u, f


@settings(max_examples=60, deadline=None)
@given(ex=finite, ey=finite, ez=finite, tx=finite, ty=finite, tz=finite, fov=st.floats(5.0, 170.0),
       px=st.floats(0, 64), py=st.floats(0, 48))
def test_ray_then_project_round_trip(ex, ey, ez, tx, ty, tz, fov, px, py):
    eye, tgt = (ex, ey, ez), (tx, ty, tz)
    d = np.subtract(tgt, eye)
    if np.linalg.norm(d) < 1e-3 or abs(d[1]) / np.linalg.norm(d) > 0.999:
        return
    cam = fw.Camera(eye=eye, target=tgt, up=(0, 1, 0), fov_y_deg=fov)
    w, h = 64, 48
    dirs = cam.ray_dirs(np.array([px]), np.array([py]), w, h)
    pts = np.asarray(eye) + dirs * 3.7
    back = cam.project(pts, w, h)[0]
    assert back[2] > 0
    np.testing.assert_allclose(back[:2], [px, py], atol=1e-6 * max(1.0, w))


def test_matrices_match_projection():
    cam = fw.Camera(eye=(1.0, 2.0, 5.0), target=(0.2, 0.8, -1.0), up=(0, 1, 0), fov_y_deg=50.0)
    w, h = 80, 50
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(100, 3)) + np.array([0.2, 0.8, -1.0])
    V = cam.view_matrix()
    P = cam.projection_matrix(w / h, 0.01, 100.0)
    hom = np.c_[pts, np.ones(len(pts))] @ (P @ V).T
    ndc = hom[:, :3] / hom[:, 3:4]
    px = (ndc[:, 0] + 1) * 0.5 * w
    py = (1 - ndc[:, 1]) * 0.5 * h
    proj = cam.project(pts, w, h)
    front = proj[:, 2] > 0
    np.testing.assert_allclose(proj[front, 0], px[front], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(proj[front, 1], py[front], rtol=1e-9, atol=1e-9)
    # view-space z equals the distance along the independently built forward axis
    r, u, f = _lookat_np(cam.eye, cam.target, cam.up)
    np.testing.assert_allclose(proj[:, 2], (pts - cam.eye) @ f, rtol=1e-12)


def test_pixel_centre_ray_directions_against_pinhole_formula():
    cam = fw.Camera(eye=(0, 0, 0), target=(0, 0, -1), up=(0, 1, 0), fov_y_deg=90.0)
    w, h = 4, 2
    xs, ys = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    d = cam.ray_dirs(xs, ys, w, h)
    # with fov 90 the image plane at distance 1 spans [-aspect, aspect] x [-1, 1]
    x_plane = (xs / w * 2 - 1) * (w / h)
    y_plane = 1 - ys / h * 2
    expect = np.stack([x_plane, y_plane, -np.ones_like(xs)], -1)
    expect /= np.linalg.norm(expect, axis=-1, keepdims=True)
    np.testing.assert_allclose(d, expect, atol=1e-12)


def test_gaze_direction_round_trip():
    cam = fw.Camera(eye=(0, 1, 3), target=(0, 1, 0), fov_y_deg=60)
    for g in [(10.0, 20.0), (160.0, 90.0), (-200.0, 50.0), (500.0, -300.0)]:
        d = cam.gaze_to_dir(g, 320, 180)
        back = cam.dir_to_gaze(d, 320, 180)
        np.testing.assert_allclose(back, g, atol=1e-6)


@pytest.mark.parametrize("fov", [0.0, -5.0, 180.0, 200.0, float("nan"), float("inf")])
def test_bad_fov(fov):
    with pytest.raises(ValueError, match="fov_y_deg"):
        fw.Camera(fov_y_deg=fov)


def test_bad_camera_vectors():
    with pytest.raises(ValueError, match="target"):
        fw.Camera(eye=(1, 1, 1), target=(1, 1, 1))
    with pytest.raises(ValueError, match="up"):
        fw.Camera(eye=(0, 0, 0), target=(0, 1, 0), up=(0, 1, 0))
    with pytest.raises(ValueError, match="eye"):
        fw.Camera(eye=(0, float("nan"), 0))
    with pytest.raises(ValueError, match="gaze_px"):
        fw.Camera().gaze_to_dir((float("nan"), 1.0), 10, 10)


def test_basis_and_params_are_cached_per_camera_and_pickle_without_them():
    import copy
    import pickle

    cam = fw.Camera(eye=(1.0, 2.0, 3.0), target=(0.0, 0.5, 0.0), fov_y_deg=47.0)
    r, u, f = cam.basis()
    assert cam.basis()[0] is r  # computed once
    with pytest.raises(ValueError):
        r[0] = 5.0  # read-only: a caller cannot corrupt the cache
    assert cam.params(64, 48) is cam.params(64, 48)
    assert cam.params(64, 48) is not cam.params(32, 24)
    # an independent basis from the definition
    fwd = np.subtract(cam.target, cam.eye) / np.linalg.norm(np.subtract(cam.target, cam.eye))
    right = np.cross(fwd, cam.up)
    right /= np.linalg.norm(right)
    np.testing.assert_allclose(f, fwd, atol=1e-15)
    np.testing.assert_allclose(r, right, atol=1e-15)
    for other in (pickle.loads(pickle.dumps(cam)), copy.deepcopy(cam)):
        assert other == cam and hash(other) == hash(cam)
        np.testing.assert_array_equal(other.basis()[2], f)
        assert other.params(64, 48).width == 64


@settings(max_examples=40, deadline=None)
@given(ex=finite, ey=finite, ez=finite, tx=finite, ty=finite, tz=finite, fov=st.floats(5.0, 170.0),
       w=st.integers(1, 4096), h=st.integers(1, 4096))
def test_params_fields_against_numpy_basis_and_cache_keys(ex, ey, ez, tx, ty, tz, fov, w, h):
    """The kernels' struct holds the independent float64 frame rounded to float32, and the cache's fast path
    (plain ints) never lets a size through that the checked path would refuse."""
    eye, tgt = (ex, ey, ez), (tx, ty, tz)
    f = np.subtract(tgt, eye)
    if not np.linalg.norm(f) > 1e-3 or abs(f[1]) / np.linalg.norm(f) > 0.999:
        return
    cam = fw.Camera(eye=eye, target=tgt, fov_y_deg=fov)
    r, u, fwd = _lookat_np(eye, tgt, cam.up)
    p = cam.params(w, h)
    for got, want in ((p.eye, eye), (p.right, r), (p.up, u), (p.forward, fwd)):
        np.testing.assert_allclose(np.array(got, dtype=np.float64), np.float32(want), rtol=0, atol=1e-6)
    assert p.width == w and p.height == h
    assert np.float32(p.aspect) == np.float32(w / h)
    assert np.float32(p.tan_half_fov_y) == np.float32(math.tan(math.radians(fov) / 2))
    assert cam.params(np.int64(w), h) is p  # the checked path finds the same entry
    for bad in ((float(w), h), (w, True), (0, h), (w, 16385)):
        with pytest.raises(ValueError):
            cam.params(*bad)


@settings(max_examples=60, deadline=None)
@given(a=st.tuples(finite, finite, finite), b=st.tuples(finite, finite, finite))
def test_rotation_deg_to_against_numpy(a, b):
    if not (np.linalg.norm(a) > 1e-3 and np.linalg.norm(b) > 1e-3):
        return
    if abs(a[1]) / np.linalg.norm(a) > 0.999 or abs(b[1]) / np.linalg.norm(b) > 0.999:
        return
    c0 = fw.Camera(eye=(0.0, 0.0, 0.0), target=a)
    c1 = fw.Camera(eye=(0.0, 0.0, 0.0), target=b)
    fa, fb = np.asarray(a) / np.linalg.norm(a), np.asarray(b) / np.linalg.norm(b)
    want = np.degrees(np.arccos(np.clip(fa @ fb, -1.0, 1.0)))
    # arccos is ill-conditioned near 0 and 180 degrees: compare through the cosine there
    got = c0.rotation_deg_to(c1)
    assert abs(math.cos(math.radians(got)) - math.cos(math.radians(want))) < 1e-12
    assert 0.0 <= got <= 180.0
    assert c0.rotation_deg_to(c0) < 1e-5


def _setter_params(cam, w, h):
    """The kernels' struct built by Warp's per-field setters (what Camera.params did before its one-write
    path): the reference for the bytes it writes."""
    import warp as wp

    from foveawarp.kernels.camera import CameraParams

    r, u, f = (tuple(float(v) for v in a) for a in cam.basis())
    c = CameraParams()
    c.eye = wp.vec3(*(float(v) for v in cam.eye))
    c.right = wp.vec3(*r)
    c.up = wp.vec3(*u)
    c.forward = wp.vec3(*f)
    c.tan_half_fov_y = cam.tan_half_fov_y
    c.aspect = float(w) / float(h)
    c.width = w
    c.height = h
    return c


@settings(max_examples=60, deadline=None)
@given(e=st.tuples(*[st.floats(-1e6, 1e6, allow_nan=False)] * 3), d=st.tuples(*[st.floats(-1, 1)] * 3),
       fov=st.floats(1.0, 179.0), w=st.integers(1, 16384), h=st.integers(1, 16384),
       huge=st.sampled_from([0.0, 1e39, -3.5e38, 1e300]))
def test_params_bytes_equal_the_per_field_setters(e, d, fov, w, h, huge):
    """Camera.params writes the struct's 64 bytes in one go: the same bytes (and the same Python-side field
    values) as Warp's setters, float32 rounding included; an eye beyond float32's range (``huge``) takes the
    setters' path, which rounds it to an infinity."""
    import ctypes

    eye = (e[0] + huge, e[1], e[2])
    tgt = (eye[0] + d[0], eye[1] + d[1] + 0.5, eye[2] + d[2])
    if not np.isfinite(tgt).all():
        return
    try:
        cam = fw.Camera(eye=eye, target=tgt, fov_y_deg=fov)
    except ValueError:
        return  # a target too close to the eye, or looking straight up: refused before any struct is made
    got = cam.params(w, h)
    want = _setter_params(cam, w, h)
    assert ctypes.string_at(ctypes.addressof(got._ctype), 64) == ctypes.string_at(ctypes.addressof(want._ctype), 64)
    for k in ("eye", "right", "up", "forward"):
        assert list(getattr(got, k)) == list(getattr(want, k))
    for k in ("tan_half_fov_y", "aspect", "width", "height"):
        assert getattr(got, k) == getattr(want, k) and type(getattr(got, k)) is type(getattr(want, k))
    if huge and abs(eye[0]) > 3.5e38:
        assert math.isinf(got.eye[0])


def test_params_layout_check_and_setters_fallback(monkeypatch):
    """The one-write path runs only for the layout it writes: ``_params_layout_ok`` accepts the compiled
    CameraParams and refuses a structure with the same names, offsets and size but other field types; with the
    check failing, ``params`` takes Warp's setters and gives the same bytes."""
    import ctypes

    import foveawarp.camera as camera_mod
    from foveawarp.kernels.camera import CameraParams

    ct = type(CameraParams()._ctype)
    assert camera_mod._params_layout_ok(ct)
    v3 = ctypes.c_float * 3

    class WrongTypes(ctypes.Structure):  # width a float, height unsigned: same offsets and size
        _fields_ = [("eye", v3), ("right", v3), ("up", v3), ("forward", v3), ("tan_half_fov_y", ctypes.c_float),
                    ("aspect", ctypes.c_float), ("width", ctypes.c_float), ("height", ctypes.c_uint32)]

    class WrongOrder(ctypes.Structure):
        _fields_ = [("right", v3), ("eye", v3), ("up", v3), ("forward", v3), ("tan_half_fov_y", ctypes.c_float),
                    ("aspect", ctypes.c_float), ("width", ctypes.c_int32), ("height", ctypes.c_int32)]

    assert ctypes.sizeof(WrongTypes) == 64 and not camera_mod._params_layout_ok(WrongTypes)
    assert not camera_mod._params_layout_ok(WrongOrder)
    cam = fw.Camera(eye=(0.3, 1.0, 2.0), target=(0.0, 0.2, -1.0), fov_y_deg=50.0)
    types = camera_mod._warp_types()
    monkeypatch.setattr(camera_mod, "_WARP_TYPES", (types[0], types[1], False))
    got = cam.params(40, 30)
    want = _setter_params(cam, 40, 30)
    assert ctypes.string_at(ctypes.addressof(got._ctype), 64) == ctypes.string_at(ctypes.addressof(want._ctype), 64)
