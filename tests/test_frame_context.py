"""The frame context (kernels/context.py, frame_context.py): its rays and reprojection against NumPy formulas
written here, bit for bit against the camera functions the stages used before it, the device copy, and the
builder's validation."""

import math

import numpy as np
import pytest
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st

import foveawarp as fw
from foveawarp.frame_context import FrameContextBuilder
from foveawarp.kernels.camera import CameraParams, camera_project, camera_ray_dir
from foveawarp.kernels.context import (FrameContext, context_ray_dir, pixel_centre_ray_dir, project_prev,
                                       set_frame_context_kernel)


@wp.kernel(enable_backward=False)
def _context_probe_kernel(ctx: FrameContext, cam: CameraParams, cam_prev: CameraParams,
                          points: wp.array2d(dtype=wp.vec3), centre: wp.array2d(dtype=wp.vec3),
                          offset: wp.array2d(dtype=wp.vec3), proj: wp.array2d(dtype=wp.vec3),
                          same: wp.array2d(dtype=wp.int32)):
    y, x = wp.tid()
    c = pixel_centre_ray_dir(ctx, x, y)
    o = context_ray_dir(ctx, float(x) + 0.25, float(y) + 0.75)
    p = project_prev(ctx, points[y, x])
    centre[y, x] = c
    offset[y, x] = o
    proj[y, x] = p
    # the same bits as the camera functions on the camera structs the stages took before the context
    s = 1
    c0 = camera_ray_dir(cam, float(x) + 0.5, float(y) + 0.5)
    o0 = camera_ray_dir(cam, float(x) + 0.25, float(y) + 0.75)
    p0 = camera_project(cam_prev, points[y, x])
    for k in range(3):
        if c[k] != c0[k] or o[k] != o0[k] or p[k] != p0[k]:
            s = 0
    same[y, x] = s


def _frame_np(cam):
    """(right, up, forward) in float64 from eye, target and up (Gram-Schmidt, written here)."""
    f = np.subtract(cam.target, cam.eye).astype(np.float64)
    f /= np.linalg.norm(f)
    r = np.cross(f, np.asarray(cam.up, np.float64))
    r /= np.linalg.norm(r)
    return r, np.cross(r, f), f


def _rays_np(cam, px, py, w, h):
    r, u, f = _frame_np(cam)
    t = math.tan(math.radians(cam.fov_y_deg) / 2.0)
    sx = (2.0 * px / w - 1.0) * t * w / h
    sy = (1.0 - 2.0 * py / h) * t
    d = f + sx[..., None] * r + sy[..., None] * u
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def _project_np(cam, pts, w, h):
    r, u, f = _frame_np(cam)
    t = math.tan(math.radians(cam.fov_y_deg) / 2.0)
    d = pts - np.asarray(cam.eye, np.float64)
    z = d @ f
    px = ((d @ r) / (z * t * w / h) + 1.0) * 0.5 * w
    py = (1.0 - (d @ u) / (z * t)) * 0.5 * h
    return np.stack([px, py, z], axis=-1)


def _probe(cam, prev, w, h, device, seed=0):
    rng = np.random.default_rng(seed)
    view = FrameContextBuilder(w, h).build(cam, prev, (w * 0.3, h * 0.6), 7, 50.0)
    # points in front of the previous camera: along its pixel rays, 1-20 units away
    dirs = _rays_np(prev, rng.uniform(0, w, (h, w)), rng.uniform(0, h, (h, w)), w, h)
    pts = np.asarray(prev.eye) + dirs * rng.uniform(1.0, 20.0, (h, w, 1))
    out = [wp.zeros((h, w), dtype=wp.vec3, device=device) for _ in range(3)]
    same = wp.zeros((h, w), dtype=wp.int32, device=device)
    wp.launch(_context_probe_kernel, (h, w), inputs=[view.struct, cam.params(w, h), prev.params(w, h),
                                                     wp.array(pts.astype(np.float32), dtype=wp.vec3, device=device)],
              outputs=[*out, same], device=device)
    return view, pts.astype(np.float32).astype(np.float64), [a.numpy() for a in out], same.numpy()


def test_context_rays_and_reprojection_match_numpy(device):
    """Pixel-centre and offset rays within 2e-6 of the float64 formulas, reprojection within 2e-3 px (float32
    projection of points up to 20 units away), and bit for bit the camera functions' results."""
    scene = fw.load_scene("cornell")
    w, h = 37, 23
    cam, prev = scene.camera_at(0.4), scene.camera_at(0.1)
    cam = fw.Camera(eye=tuple(np.add(cam.eye, (0.3, 0.1, -0.2))), target=cam.target, up=cam.up, fov_y_deg=50.0)
    view, pts, (centre, offset, proj), same = _probe(cam, prev, w, h, device)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    np.testing.assert_allclose(centre, _rays_np(cam, xs + 0.5, ys + 0.5, w, h), rtol=0, atol=2e-6)
    np.testing.assert_allclose(offset, _rays_np(cam, xs + 0.25, ys + 0.75, w, h), rtol=0, atol=2e-6)
    want = _project_np(prev, pts, w, h)
    np.testing.assert_allclose(proj[..., :2], want[..., :2], rtol=0, atol=2e-3)
    np.testing.assert_allclose(proj[..., 2], want[..., 2], rtol=1e-5)
    assert same.all()


@settings(max_examples=40, deadline=None)
@given(e=st.tuples(*[st.floats(-20, 20)] * 3), t=st.tuples(*[st.floats(-20, 20)] * 3), fov=st.floats(1.0, 179.0),
       w=st.integers(1, 9), h=st.integers(1, 9))
def test_context_rays_finite_unit_and_equal_to_camera_functions(e, t, fov, w, h):
    """Any camera (degenerate sizes of 1 pixel, fields of view up to 179 deg): finite unit rays, the camera
    functions' bits."""
    for d in (np.subtract(t, e), np.subtract(t, np.add(e, (0.5, 0.0, 0.0)))):  # both cameras well defined
        if np.linalg.norm(d) < 1e-3 or abs(d[1]) > 0.999 * np.linalg.norm(d):
            return
    cam = fw.Camera(eye=e, target=t, up=(0, 1, 0), fov_y_deg=fov)
    prev = fw.Camera(eye=tuple(np.add(e, (0.5, 0.0, 0.0))), target=t, up=(0, 1, 0), fov_y_deg=fov)
    _, _, (centre, offset, proj), same = _probe(cam, prev, w, h, "cpu")
    assert same.all()
    for a in (centre, offset):
        assert np.isfinite(a).all()
        np.testing.assert_allclose(np.linalg.norm(a, axis=-1), 1.0, atol=2e-6)
    assert np.isfinite(proj).all()


def test_builder_fields_and_device_copy(device):
    """The struct holds both cameras' parameters, the clamped gaze, the frame index and the ray length; the
    device copy (a captured graph's launches read it) holds the same bytes."""
    scene = fw.load_scene("cornell")
    w, h = 32, 16
    cam, prev = scene.camera_at(0.2), scene.camera_at(0.0)
    b = FrameContextBuilder(w, h)
    v = b.build(cam, prev, (-5e6, 12.5), 41, 9.25)
    assert v.gaze == (-1e6, 12.5) and v.frame_index == 41 and v.max_t == 9.25
    assert v.camera is cam and v.prev_camera is prev and v.struct is b.struct
    s = v.struct
    assert list(s.gaze) == [-1e6, 12.5] and s.frame == 41 and s.max_t == 9.25
    for got, c in ((s.cam, cam), (s.cam_prev, prev)):
        want = c.params(w, h)
        for f in ("eye", "right", "up", "forward"):
            assert list(getattr(got, f)) == list(getattr(want, f)), f
        assert (got.width, got.height) == (w, h)
        assert np.float32(got.tan_half_fov_y) == np.float32(math.tan(math.radians(c.fov_y_deg) / 2.0))
    dev = wp.zeros(1, dtype=FrameContext, device=device)
    wp.launch(set_frame_context_kernel, 1, inputs=[s], outputs=[dev], device=device)
    back = dev.numpy()[0]
    assert back.tobytes() == bytes(s._ctype)
    # a second frame re-packs the same struct
    v2 = b.build(prev, prev, (3.0, 4.0), 42, 1.0)
    assert v2.struct is s and list(s.cam.eye) == list(prev.params(w, h).eye) and s.frame == 42


@pytest.mark.parametrize("args,match", [
    ({"camera": None}, "camera must be a foveawarp.Camera"),
    ({"prev_camera": "cam"}, "prev_camera must be a foveawarp.Camera"),
    ({"gaze_px": (float("nan"), 1.0)}, r"gaze_px\[0\]"),
    ({"gaze_px": (1.0,)}, "gaze_px must be 2 finite numbers"),
    ({"frame_index": -1}, "frame_index must be"),
    ({"frame_index": 1.5}, "frame_index"),
    ({"max_t": 0.0}, "max_t"),
    ({"max_t": float("inf")}, "max_t"),
    ({"max_t": float("nan")}, "max_t"),
    ({"max_t": "far"}, "max_t"),
])
def test_builder_bad_input(args, match):
    scene = fw.load_scene("cornell")
    kw = {"camera": scene.camera, "prev_camera": scene.camera, "gaze_px": (1.0, 2.0), "frame_index": 0,
          "max_t": 10.0, **args}
    with pytest.raises(ValueError, match=match):
        FrameContextBuilder(8, 8).build(**kw)


def test_builder_bad_size():
    with pytest.raises(ValueError, match="width"):
        FrameContextBuilder(0, 8)
