"""Camera: eye / target / up / vertical field of view; matrices, rays, projection, gaze <-> direction."""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np

from .config import check_array, check_finite, check_int_range, check_range, check_vec, show

__all__ = ["Camera"]


def _vec3(name: str, v) -> tuple:
    return check_vec(name, v, 3)


def _size(width, height) -> tuple:
    return check_int_range("width", width, 1, 16384), check_int_range("height", height, 1, 16384)


@dataclass(frozen=True)
class Camera:
    """A pinhole camera looking from ``eye`` at ``target``.

    Attributes:
        eye: eye position, world units.
        target: a point the camera looks at; must differ from ``eye``.
        up: approximate up vector; must not be parallel to ``target - eye``.
        fov_y_deg: vertical field of view in degrees, in (0, 180).
    """

    eye: tuple = (0.0, 1.0, 3.5)
    target: tuple = (0.0, 1.0, 0.0)
    up: tuple = (0.0, 1.0, 0.0)
    fov_y_deg: float = 60.0

    def __post_init__(self):
        object.__setattr__(self, "eye", _vec3("Camera.eye", self.eye))
        object.__setattr__(self, "target", _vec3("Camera.target", self.target))
        object.__setattr__(self, "up", _vec3("Camera.up", self.up))
        check_range("Camera.fov_y_deg", self.fov_y_deg, 0.0, 180.0, lo_open=True, hi_open=True)
        object.__setattr__(self, "fov_y_deg", float(self.fov_y_deg))
        # plain float math on 3-tuples: a camera is made every frame, and NumPy's per-call cost on 3-vectors
        # (np.cross, np.linalg.norm) made Camera(...) + params() ~0.16 ms of host time per frame
        f = _sub3(self.target, self.eye)
        n = _norm3(f)
        if not n > 0.0 or not math.isfinite(n):
            raise ValueError(f"Camera.target must differ from Camera.eye (both {self.eye!r})")
        f = (f[0] / n, f[1] / n, f[2] / n)
        u = self.up
        un = _norm3(u)
        if not un > 0.0:
            raise ValueError(f"Camera.up must be a non-zero vector, got {self.up!r}")
        if abs(f[0] * (u[0] / un) + f[1] * (u[1] / un) + f[2] * (u[2] / un)) > 1.0 - 1e-9:
            raise ValueError(f"Camera.up {self.up!r} must not be parallel to the view direction {f!r}")

    def __getstate__(self):  # pickle / copy without the per-camera caches (basis, Warp structs)
        return {k: v for k, v in self.__dict__.items() if not k.startswith("_")}

    def __setstate__(self, state):
        for k, v in state.items():
            object.__setattr__(self, k, v)

    # -- frame ---------------------------------------------------------------------------------------
    def basis(self):
        """(right, up, forward) as float64 unit vectors (read-only); right-handed, forward = view direction.
        Computed once per camera (a frame asks for it several times)."""
        cached = self.__dict__.get("_basis")
        if cached is not None:
            return cached
        out = []
        for v in self._basis_floats():
            a = np.array(v, dtype=np.float64)
            a.setflags(write=False)
            out.append(a)
        r, u, f = out
        object.__setattr__(self, "_basis", (r, u, f))
        return r, u, f

    def _basis_floats(self) -> tuple:
        """``basis()`` as three 3-tuples of Python floats (the same values), computed once per camera: the
        per-frame host path (``params``, ``rotation_deg_to``) reads these, not NumPy arrays, whose elements
        cost a conversion each."""
        cached = self.__dict__.get("_basis_t")
        if cached is not None:
            return cached
        f = _sub3(self.target, self.eye)
        n = _norm3(f)
        f = (f[0] / n, f[1] / n, f[2] / n)
        r = _cross3(f, self.up)
        n = _norm3(r)
        r = (r[0] / n, r[1] / n, r[2] / n)
        u = _cross3(r, f)
        object.__setattr__(self, "_basis_t", (r, u, f))
        return r, u, f

    @property
    def tan_half_fov_y(self) -> float:
        return math.tan(math.radians(self.fov_y_deg) * 0.5)

    def view_matrix(self) -> np.ndarray:
        """4x4 world -> view (OpenGL convention: camera looks down -z)."""
        r, u, f = self.basis()
        e = np.asarray(self.eye, dtype=np.float64)
        m = np.eye(4)
        m[0, :3], m[1, :3], m[2, :3] = r, u, -f
        m[:3, 3] = -m[:3, :3] @ e
        return m

    def projection_matrix(self, aspect: float, near: float = 0.01, far: float = 1000.0) -> np.ndarray:
        """4x4 OpenGL perspective projection for ``aspect`` = width / height."""
        check_range("aspect", aspect, 0.0, None, lo_open=True)
        check_range("near", near, 0.0, None, lo_open=True)
        check_range("far", far, near, None, lo_open=True)
        t = 1.0 / self.tan_half_fov_y
        p = np.zeros((4, 4))
        p[0, 0] = t / aspect
        p[1, 1] = t
        p[2, 2] = (far + near) / (near - far)
        p[2, 3] = 2.0 * far * near / (near - far)
        p[3, 2] = -1.0
        return p

    # -- rays and projection (NumPy; the kernels use kernels.camera with the same formulas) ----------
    def ray_dirs(self, px, py, width: int, height: int) -> np.ndarray:
        """Unit ray directions through continuous pixel positions (centres at x + 0.5); ``px``, ``py`` finite
        (off screen is valid), ``width``, ``height`` integers in [1, 16384]."""
        width, height = _size(width, height)
        px = check_array("px", px)
        py = check_array("py", py)
        r, u, f = self.basis()
        t = self.tan_half_fov_y
        sx = (2.0 * np.asarray(px, dtype=np.float64) / width - 1.0) * t * (width / height)
        sy = (1.0 - 2.0 * np.asarray(py, dtype=np.float64) / height) * t
        d = f + sx[..., None] * r + sy[..., None] * u
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def project(self, points, width: int, height: int) -> np.ndarray:
        """World points (..., 3) -> (..., 3) of (px, py, z_view); z_view <= 0 is behind the eye."""
        width, height = _size(width, height)
        points = check_array("points", points)
        if points.ndim < 1 or points.shape[-1] != 3:
            raise ValueError(f"points must have shape (..., 3), got {points.shape}")
        r, u, f = self.basis()
        d = np.asarray(points, dtype=np.float64) - np.asarray(self.eye)
        z = d @ f
        t = self.tan_half_fov_y
        with np.errstate(divide="ignore", invalid="ignore"):
            sx = (d @ r) / (z * t * (width / height))
            sy = (d @ u) / (z * t)
        px = np.where(z > 0, (sx + 1.0) * 0.5 * width, 0.0)
        py = np.where(z > 0, (1.0 - sy) * 0.5 * height, 0.0)
        return np.stack([px, py, z], axis=-1)

    def gaze_to_dir(self, gaze_px, width: int, height: int) -> np.ndarray:
        """Gaze point in pixels -> unit world direction from the eye."""
        g = _check_gaze(gaze_px)
        width, height = _size(width, height)
        return self.ray_dirs(np.array(g[0]), np.array(g[1]), width, height)

    def dir_to_gaze(self, direction, width: int, height: int) -> tuple:
        """Unit world direction -> gaze point in pixels (it may lie off screen)."""
        d = np.asarray(_vec3("direction", direction))
        if not np.linalg.norm(d) > 0:
            raise ValueError(f"direction must be a non-zero vector, got {show(direction)}")
        p = self.project(np.asarray(self.eye) + d, width, height)
        if p[2] <= 0:
            raise ValueError(f"direction {tuple(d)!r} points behind the camera")
        return float(p[0]), float(p[1])

    def params(self, width: int, height: int):
        """The Warp struct the kernels take (made once per camera and size: the per-frame G-buffer launch asks
        for it, and its host time is on the frame's critical path)."""
        cache = self.__dict__.get("_params")
        if cache is not None and type(width) is int and type(height) is int:
            c = cache.get((width, height))
            if c is not None:
                return c
        width, height = _size(width, height)
        cache = self.__dict__.setdefault("_params", {})
        c = cache.get((width, height))
        if c is not None:
            return c
        params_type, vec3, packed = _warp_types()
        r, u, f = self._basis_floats()
        e = self.eye
        c = params_type()
        tan, aspect = self.tan_half_fov_y, float(width) / float(height)
        if not (packed and _pack_params(c, e, r, u, f, tan, aspect, width, height)):
            # Warp's per-field setters: another struct layout, or a value beyond float32's range (rounded to inf)
            c.eye = vec3(e[0], e[1], e[2])
            c.right = vec3(r[0], r[1], r[2])
            c.up = vec3(u[0], u[1], u[2])
            c.forward = vec3(f[0], f[1], f[2])
            c.tan_half_fov_y = tan
            c.aspect = aspect
            c.width = width
            c.height = height
        cache[(width, height)] = c
        return c

    def rotation_deg_to(self, other: "Camera") -> float:
        """Angle in degrees between this camera's view direction and ``other``'s."""
        if not isinstance(other, Camera):
            raise ValueError(f"other must be a foveawarp.Camera, got {show(other)} ({type(other).__name__})")
        f0 = self._basis_floats()[2]
        f1 = other._basis_floats()[2]
        d = f0[0] * f1[0] + f0[1] * f1[1] + f0[2] * f1[2]
        return math.degrees(math.acos(max(-1.0, min(1.0, d))))


_WARP_TYPES = None


# CameraParams as bytes: eye, right, up, forward (float32 x 3 each), tan_half_fov_y, aspect (float32), width,
# height (int32), little-endian and unpadded; _warp_types checks that the compiled struct has this layout
_PARAMS_PACK = struct.Struct("<14f2i")
_PARAMS_FIELDS = (("eye", 0), ("right", 12), ("up", 24), ("forward", 36), ("tan_half_fov_y", 48), ("aspect", 52),
                  ("width", 56), ("height", 60))


def _params_layout_ok(ct) -> bool:
    """Whether the ctypes structure ``ct`` of CameraParams is laid out as ``_PARAMS_PACK`` writes it: the field
    names and offsets of ``_PARAMS_FIELDS``, four 3-float32 arrays, two float32, two int32, 64 bytes, a
    little-endian host."""
    import ctypes
    import sys

    fields = list(ct._fields_)
    if tuple((name, getattr(ct, name).offset) for name, _ in fields) != _PARAMS_FIELDS:
        return False
    if ctypes.sizeof(ct) != _PARAMS_PACK.size or sys.byteorder != "little":
        return False
    kinds = []
    for _, t in fields:
        if issubclass(t, ctypes.Array):
            kinds.append("vec3" if (t._length_ == 3 and t._type_ is ctypes.c_float) else "?")
        else:
            kinds.append({ctypes.c_float: "f32", ctypes.c_int32: "i32"}.get(t, "?"))
    return kinds == ["vec3"] * 4 + ["f32"] * 2 + ["i32"] * 2


def _pack_params(c, e, r, u, f, tan: float, aspect: float, width: int, height: int) -> bool:
    """Write CameraParams ``c``'s 64 bytes in one go (its layout checked by ``_warp_types``): about half the time of
    Warp's per-field setters, on the frame's critical path; the same float32 values. False (nothing usable written)
    where a value is beyond float32's range."""
    try:
        _PARAMS_PACK.pack_into(memoryview(c._ctype).cast("B"), 0, e[0], e[1], e[2], r[0], r[1], r[2], u[0], u[1],
                               u[2], f[0], f[1], f[2], tan, aspect, width, height)
    except OverflowError:
        return False
    d = c.__dict__  # the vectors' attributes alias the struct's bytes; the scalars' are Python values
    d["tan_half_fov_y"], d["aspect"], d["width"], d["height"] = tan, aspect, width, height
    return True


def _warp_types() -> tuple:
    """(``kernels.camera.CameraParams``, ``wp.vec3``, whether ``params`` may write the struct's bytes in one go),
    imported on first use (this module does not need Warp otherwise) and kept: ``params`` runs before every frame's
    G-buffer launch. Where the compiled struct's layout differs from ``_PARAMS_PACK``'s (``_params_layout_ok``),
    ``params`` uses Warp's per-field setters."""
    global _WARP_TYPES
    if _WARP_TYPES is None:
        import warp as wp

        from .kernels.camera import CameraParams

        _WARP_TYPES = (CameraParams, wp.vec3, _params_layout_ok(type(CameraParams()._ctype)))
    return _WARP_TYPES


def _sub3(a, b) -> tuple:
    return (float(a[0]) - float(b[0]), float(a[1]) - float(b[1]), float(a[2]) - float(b[2]))


def _norm3(a) -> float:
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


def _cross3(a, b) -> tuple:
    """a x b with NumPy's formula (np.cross), in float64."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _check_gaze(gaze_px) -> tuple:
    try:
        g = None if isinstance(gaze_px, (str, bytes)) else tuple(gaze_px)
    except TypeError:
        g = None
    if g is None or len(g) != 2:
        raise ValueError(f"gaze_px must be 2 finite numbers (x, y) in pixels, got {show(gaze_px)}")
    return tuple(check_finite(f"gaze_px[{i}]", c) for i, c in enumerate(g))
