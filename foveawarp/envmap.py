"""An equirectangular HDR environment map as a light, on the host and on a device.

:class:`Environment` holds an ``(H, W, 3)`` float32 linear radiance map (from ``foveawarp.io.images
.load_environment`` or an array), a ``scale`` and a ``to_world`` rotation, in Mitsuba 3's ``envmap`` convention
(see ``foveawarp.kernels.envmap``; maps under 3 rows or 2 columns padded as Mitsuba pads them, :func:`pad_map`):
the same file with the same ``scale`` and ``to_world`` gives the same radiance in every direction in both
renderers. It builds the importance-sampling tables once (:func:`build_distribution`,
NumPy, float64): per cell between neighbouring texel positions the mean corner luminance, the marginal CDF over
bands of latitude and one conditional CDF over columns per band, and the solid-angle pdf of each cell.
:meth:`Environment.to_device` copies them into the :class:`foveawarp.kernels.envmap.EnvironmentMap` struct that
shading kernels take as one argument and use with ``env_eval``, ``env_sample`` and ``env_pdf``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Optional, Union

import numpy as np
import warp as wp

from .config import check_range, show
from .kernels import envmap as ek

__all__ = ["MAX_ENVIRONMENT_TEXELS", "Distribution", "build_distribution", "pad_map", "check_rotation",
           "Environment"]

# most texels of a map: the kernels index texels and CDF entries with int32
MAX_ENVIRONMENT_TEXELS = 1 << 28
# largest deviation of to_world from a rotation (max |R^T R - I| entry) that is accepted and re-orthonormalized
_ROTATION_TOL = 1e-4


@dataclasses.dataclass(frozen=True)
class Distribution:
    """The importance-sampling tables of a map (float64, see ``foveawarp.kernels.envmap``).

    Attributes:
        cell_luminance: (B, W) mean luminance of each cell's four corner texels (all ones for a black map).
        cell_solid_angle: (B, W) solid angle of each cell in steradians (sums to 4 pi).
        cell_pdf: (B, W) solid-angle pdf inside each cell.
        marginal_cdf: (B + 1,) CDF over bands, 0 first and 1 last.
        conditional_cdf: (B, W + 1) per band the CDF over its columns, 0 first and 1 last.
        luminance_integral: sum of luminance x solid angle over the cells before any fallback (0 for a black map).
    """

    cell_luminance: np.ndarray
    cell_solid_angle: np.ndarray
    cell_pdf: np.ndarray
    marginal_cdf: np.ndarray
    conditional_cdf: np.ndarray
    luminance_integral: float


def _cdf(weights: np.ndarray) -> np.ndarray:
    """Normalized CDFs along the last axis, 0 first and exactly 1 last; rows of zero weight become uniform."""
    w = np.asarray(weights, np.float64)
    tot = w.sum(axis=-1, keepdims=True)
    w = np.where(tot > 0.0, w, 1.0)
    c = np.cumsum(w, axis=-1)
    c = c / c[..., -1:]
    out = np.concatenate([np.zeros(c.shape[:-1] + (1,)), c], axis=-1)
    out[..., -1] = 1.0
    return out


def build_distribution(radiance: np.ndarray) -> Distribution:
    """The sampling tables of an ``(H, W, 3)`` non-negative radiance map (scale does not change them)."""
    a = np.asarray(radiance, np.float64)
    h, w = a.shape[:2]
    lum = a @ np.asarray(ek.LUMINANCE, np.float64)  # (H, W)
    b = max(h - 1, 1)
    rows0 = np.arange(b)
    rows1 = np.minimum(rows0 + 1, h - 1)
    cols0 = np.arange(w)
    cols1 = (cols0 + 1) % w
    cell_lum = 0.25 * (lum[rows0][:, cols0] + lum[rows0][:, cols1] + lum[rows1][:, cols0] + lum[rows1][:, cols1])
    theta = np.pi * np.arange(b + 1) / b
    band = np.cos(theta[:-1]) - np.cos(theta[1:])  # (B,)
    solid = np.broadcast_to((2.0 * np.pi / w) * band[:, None], (b, w))
    total = float(np.sum(cell_lum * solid))
    weights = cell_lum if total > 0.0 else np.ones_like(cell_lum)  # a black map: uniform over the sphere
    z = float(np.sum(weights * solid))
    return Distribution(
        cell_luminance=weights,
        cell_solid_angle=np.ascontiguousarray(solid),
        cell_pdf=weights / z,
        marginal_cdf=_cdf(np.sum(weights * solid, axis=1)),
        conditional_cdf=_cdf(weights),
        luminance_integral=total,
    )


def check_rotation(name: str, m) -> np.ndarray:
    """A (3, 3) rotation as float64, re-orthonormalized; a (4, 4) affine transform's upper 3 x 3 is taken (the
    translation does not move a direction). Anything else (not a rotation within 1e-4, a reflection, a scale,
    NaN) raises ``ValueError``."""
    try:
        a = np.asarray(m, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a 3x3 rotation matrix, got {show(m)}") from None
    if a.shape == (4, 4):
        if not np.isfinite(a).all() or not np.allclose(a[3], [0.0, 0.0, 0.0, 1.0]):
            raise ValueError(f"{name} as a 4x4 matrix must be affine (last row 0, 0, 0, 1), got {show(a.tolist())}")
        a = a[:3, :3]
    if a.shape != (3, 3) or not np.isfinite(a).all():
        raise ValueError(f"{name} must be a finite 3x3 rotation matrix, got {show(np.asarray(m).tolist())}")
    err = float(np.abs(a.T @ a - np.eye(3)).max())
    if err > _ROTATION_TOL or np.linalg.det(a) <= 0.0:
        raise ValueError(f"{name} must be a rotation (orthonormal, determinant +1, to within {_ROTATION_TOL}), got "
                         f"{show(a.tolist())} (max |R^T R - I| = {err:.3g}, det = {np.linalg.det(a):.6g})")
    u, _, vt = np.linalg.svd(a)
    return u @ vt


def pad_map(radiance: np.ndarray) -> np.ndarray:
    """The map padded to at least 3 rows and 2 columns by repeating its last row and column, as Mitsuba's
    ``envmap`` does (``Bitmap::pad_to``): rows sit at ``v = j / (H - 1)``, so a 2-row map's second row covers
    the lower hemisphere (from ``v = 0.5``) and a 1-row or 1-column map is constant along that axis."""
    a = np.asarray(radiance, np.float32)
    h, w = a.shape[:2]
    if h < 3:
        a = np.concatenate([a, np.repeat(a[-1:], 3 - h, axis=0)], axis=0)
    if w < 2:
        a = np.concatenate([a, np.repeat(a[:, -1:], 2 - w, axis=1)], axis=1)
    return np.ascontiguousarray(a)


def _check_radiance(name: str, array) -> np.ndarray:
    if hasattr(array, "numpy") and not isinstance(array, np.ndarray):
        array = array.numpy()
    try:
        a = np.asarray(array)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be an (H, W, 3) array of linear radiance, got {show(array)}") from None
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"{name} must be an (H, W, 3) array of linear radiance with H, W >= 1, got shape "
                         f"{a.shape}")
    if a.dtype.kind not in "fiu":
        raise ValueError(f"{name} must hold real numbers, got dtype {a.dtype}")
    if a.shape[0] * a.shape[1] > MAX_ENVIRONMENT_TEXELS:
        raise ValueError(f"{name} must have at most {MAX_ENVIRONMENT_TEXELS} texels, got {a.shape[1]} x "
                         f"{a.shape[0]}")
    a = a.astype(np.float32)
    for what, bad in (("NaN", np.isnan(a)), ("Inf", np.isinf(a)), ("negative", a < 0)):
        if bad.any():
            idx = tuple(int(k) for k in np.argwhere(bad)[0])
            raise ValueError(f"{name} must hold finite radiance values >= 0, got {int(bad.sum())} {what} value(s), "
                             f"the first {show(a[idx])} at (row, column, channel) {idx}")
    return np.ascontiguousarray(a)


class Environment:
    """An environment light: an equirectangular radiance map, a scale and a rotation.

    Args:
        radiance: ``(H, W, 3)`` linear radiance, row 0 the top of the image (the local +Y), finite and >= 0.
        scale: multiplies the radiance, finite and >= 0 (Mitsuba's ``scale``).
        to_world: rotation from the map's frame to world space, (3, 3) or a (4, 4) affine transform (its
            translation ignored, as for any direction); None for the identity (Mitsuba's ``to_world``).
        name: a label for messages.

    Attributes:
        radiance: the map as given (float32); texels: the map the kernels read (:func:`pad_map`), width and
            height its size; scale, to_world (float64 (3, 3)), name, distribution (:class:`Distribution`).
    """

    def __init__(self, radiance, *, scale: float = 1.0, to_world=None, name: str = "environment"):
        self.name = str(name)
        self.radiance = _check_radiance(f"environment {self.name!r} radiance", radiance)
        self.scale = check_range(f"environment {self.name!r} scale", scale, 0.0)
        self.to_world = np.eye(3) if to_world is None else check_rotation(f"environment {self.name!r} to_world",
                                                                          to_world)
        self.texels = pad_map(self.radiance)
        self.height, self.width = self.texels.shape[:2]
        self.distribution = build_distribution(self.texels)
        self._device_data = {}

    @classmethod
    def from_array(cls, radiance, scale: float = 1.0, to_world=None, *, name: str = "environment") -> "Environment":
        """An environment from an ``(H, W, 3)`` linear radiance array."""
        return cls(radiance, scale=scale, to_world=to_world, name=name)

    @classmethod
    def from_file(cls, path: Union[str, Path], scale: float = 1.0, to_world=None) -> "Environment":
        """An environment from a Radiance ``.hdr`` or OpenEXR ``.exr`` file (``load_environment``)."""
        from .io.images import load_environment

        return cls(load_environment(path), scale=scale, to_world=to_world, name=str(path))

    @classmethod
    def constant(cls, rgb, scale: float = 1.0) -> "Environment":
        """The same radiance ``rgb`` (3 values >= 0) from every direction (a 1 x 1 map: sampled uniformly over the
        sphere, pdf 1 / (4 pi))."""
        try:
            c = np.asarray(rgb, dtype=np.float64)
        except (TypeError, ValueError):
            c = None
        if c is None or c.shape != (3,):
            raise ValueError(f"constant environment rgb must be 3 numbers, got {show(rgb)}")
        return cls(c.reshape(1, 1, 3), scale=scale, name=f"constant {tuple(float(x) for x in c)}")

    @classmethod
    def of(cls, value) -> Optional["Environment"]:
        """The :class:`Environment` of a ``Scene.environment`` value: None for None, an Environment as it is, an
        (H, W, 3) array (``from_array``), a path (``from_file``) or a scene file's record (``from_data``)."""
        if value is None or isinstance(value, Environment):
            return value
        if isinstance(value, np.ndarray):
            return cls.from_array(value)
        if isinstance(value, (str, Path)):
            return cls.from_file(value)
        return cls.from_data(value)

    @classmethod
    def from_data(cls, data) -> "Environment":
        """From any object with ``image`` (a path or an (H, W, 3) array), ``scale`` and ``to_world``, such as a
        scene file's environment record."""
        try:
            image, scale, to_world = data.image, data.scale, data.to_world
        except AttributeError:
            raise ValueError(f"environment data must have image, scale and to_world, got {show(data)}") from None
        if isinstance(image, (str, Path)):
            return cls.from_file(image, scale=scale, to_world=to_world)
        return cls(image, scale=scale, to_world=to_world, name=getattr(data, "name", "") or "environment")

    @property
    def is_black(self) -> bool:
        """True when no direction carries light (zero map or zero scale)."""
        return self.scale == 0.0 or self.distribution.luminance_integral == 0.0

    def to_device(self, device=None) -> ek.EnvironmentMap:
        """The :class:`foveawarp.kernels.envmap.EnvironmentMap` struct on ``device`` (built once per device)."""
        d = wp.get_device(device)
        key = str(d)
        if key in self._device_data:
            return self._device_data[key]
        dist = self.distribution
        e = ek.EnvironmentMap()
        e.texels = wp.array(self.texels.reshape(-1, 3), dtype=wp.vec3, device=d)
        e.width = int(self.width)
        e.height = int(self.height)
        e.num_bands = int(dist.cell_pdf.shape[0])
        e.marginal_cdf = wp.array(dist.marginal_cdf.astype(np.float32), dtype=float, device=d)
        e.conditional_cdf = wp.array(dist.conditional_cdf.astype(np.float32).reshape(-1), dtype=float, device=d)
        e.cell_pdf = wp.array(dist.cell_pdf.astype(np.float32).reshape(-1), dtype=float, device=d)
        e.to_world = wp.mat33(*self.to_world.astype(np.float32).ravel())
        e.to_local = wp.mat33(*self.to_world.T.astype(np.float32).ravel())
        e.scale = float(self.scale)
        e.luminance_integral = float(dist.luminance_integral * self.scale)
        self._device_data[key] = e
        return e

    # host-side calls (one launch each; for tests, tools and users, not the per-frame path)

    def eval(self, directions, *, device=None) -> np.ndarray:
        """``(N, 3)`` scaled radiance arriving from world ``directions`` (N, 3)."""
        dirs = _check_directions(directions)
        d = wp.get_device(device)
        out = wp.empty(len(dirs), dtype=wp.vec3, device=d)
        if len(dirs):
            wp.launch(ek.env_eval_kernel, dim=len(dirs), device=d,
                      inputs=[self.to_device(d), wp.array(dirs, dtype=wp.vec3, device=d)], outputs=[out])
        return out.numpy().reshape(-1, 3)

    def pdf(self, directions, *, device=None) -> np.ndarray:
        """``(N,)`` solid-angle pdf of :meth:`sample` at world ``directions`` (N, 3)."""
        dirs = _check_directions(directions)
        d = wp.get_device(device)
        out = wp.empty(len(dirs), dtype=float, device=d)
        if len(dirs):
            wp.launch(ek.env_pdf_kernel, dim=len(dirs), device=d,
                      inputs=[self.to_device(d), wp.array(dirs, dtype=wp.vec3, device=d)], outputs=[out])
        return out.numpy()

    def sample(self, u, *, device=None) -> tuple:
        """Directions drawn with uniform numbers ``u`` (N, 2) in [0, 1) -> (directions (N, 3), radiance (N, 3),
        pdf (N,))."""
        uu = np.asarray(u, dtype=np.float32)
        if uu.ndim != 2 or uu.shape[1] != 2:
            raise ValueError(f"u must be an (N, 2) array of uniform numbers, got shape {uu.shape}")
        d = wp.get_device(device)
        n = len(uu)
        outs = [wp.empty(n, dtype=wp.vec3, device=d), wp.empty(n, dtype=wp.vec3, device=d),
                wp.empty(n, dtype=float, device=d)]
        if n:
            wp.launch(ek.env_sample_kernel, dim=n, device=d,
                      inputs=[self.to_device(d), wp.array(np.ascontiguousarray(uu), dtype=wp.vec2, device=d)],
                      outputs=outs)
        return outs[0].numpy().reshape(-1, 3), outs[1].numpy().reshape(-1, 3), outs[2].numpy()

    def __repr__(self) -> str:
        return f"Environment({self.name!r}, {self.width} x {self.height}, scale={self.scale})"


def _check_directions(directions) -> np.ndarray:
    a = np.asarray(directions, dtype=np.float32)
    if a.ndim == 1 and a.shape == (3,):
        a = a[None]
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"directions must be an (N, 3) array, got shape {a.shape}")
    return np.ascontiguousarray(a)
