"""Saliency terms of the sampling map (thesis eq. 3): CIE-Lab albedo gradient, normal gradient, DoF factor.

Conventions:
    * Albedo is *linear* RGB (the G-buffer's reflectance). It is converted to CIE-Lab (D65, 2 deg observer)
      with the sRGB primaries, without any transfer function: ``linear_rgb_to_lab(c)`` equals
      ``skimage.color.rgb2lab(srgb_encode(c))`` (skimage decodes its sRGB input first; this function starts from the
      decoded values). Same constants as skimage: ``xyz_from_rgb``, white (0.95047, 1, 1.08883), the
      0.008856 / 7.787 knee.
    * Gradients are the 3x3 Sobel operator with edge-clamped (replicated) borders, which equals
      ``scipy.ndimage.sobel``'s default "reflect" mode for a 3x3 stencil. A step of height h between two
      neighbours gives a magnitude of ``SOBEL_GAIN * h``.
"""

import warp as wp

from .load import load1_vec3, load_i32, load_vec3, nine_equal_i32, nine_equal_vec3

# Sobel response to a unit step between neighbouring pixels (1 + 2 + 1).
SOBEL_GAIN = 4.0
# Lab step (Delta E*76 units) across one pixel that saturates dA = 1 at SaliencyConfig.albedo_scale = 1.
# A just-noticeable difference is about 2.3; 20 is a clearly visible edge.
LAB_STEP_FULL = 20.0
# Step of a unit-normal component across one pixel that saturates dN = 1 at normal_scale = 1 (~30 deg crease).
NORMAL_STEP_FULL = 0.5


@wp.func
def lab_f(t: float) -> float:
    """CIE-Lab companding f(t) (skimage's knee: cube root above 0.008856, linear below)."""
    if t > 0.008856:
        return wp.cbrt(t)
    return 7.787 * t + 16.0 / 116.0


@wp.func
def linear_rgb_to_lab(c: wp.vec3) -> wp.vec3:
    """Linear sRGB-primaries RGB -> CIE-Lab (D65, 2 deg). L in [0, 100] for inputs in [0, 1]."""
    x = 0.412453 * c[0] + 0.357580 * c[1] + 0.180423 * c[2]
    y = 0.212671 * c[0] + 0.715160 * c[1] + 0.072169 * c[2]
    z = 0.019334 * c[0] + 0.119193 * c[1] + 0.950227 * c[2]
    fx = lab_f(x / 0.95047)
    fy = lab_f(y)
    fz = lab_f(z / 1.08883)
    return wp.vec3(116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz))


@wp.func
def sobel_max_channel(a00: wp.vec3, a01: wp.vec3, a02: wp.vec3, a10: wp.vec3, a12: wp.vec3,
                      a20: wp.vec3, a21: wp.vec3, a22: wp.vec3) -> float:
    """max over the 3 channels of the Sobel gradient magnitude; aRC = sample at row y-1+R, column x-1+C."""
    gx = (a02 + 2.0 * a12 + a22) - (a00 + 2.0 * a10 + a20)
    gy = (a20 + 2.0 * a21 + a22) - (a00 + 2.0 * a01 + a02)
    m0 = gx[0] * gx[0] + gy[0] * gy[0]
    m1 = gx[1] * gx[1] + gy[1] * gy[1]
    m2 = gx[2] * gx[2] + gy[2] * gy[2]
    return wp.sqrt(wp.max(m0, wp.max(m1, m2)))


@wp.func
def clamped_neighbours(x: int, y: int, w: int, h: int):
    """(x - 1, x + 1, y - 1, y + 1) clamped to a w x h image: the 3x3 stencil's edge-replicated taps."""
    return wp.max(x - 1, 0), wp.min(x + 1, w - 1), wp.max(y - 1, 0), wp.min(y + 1, h - 1)


@wp.func
def sobel_vec3(a: wp.array2d(dtype=wp.vec3), x: int, y: int) -> float:
    """Sobel gradient magnitude at (x, y) of a 3-channel image, max over the channels (edge-clamped). A
    neighbourhood whose nine values are all equal (a flat face's normals) returns 0 without the arithmetic: the
    operator's two sums are then the same operations on the same values, so their difference is exactly 0."""
    if nine_equal_vec3(a, y, x) != 0:  # the CPU's word compare of the same test (kernels/load.py)
        return 0.0
    xm, xp, ym, yp = clamped_neighbours(x, y, a.shape[1], a.shape[0])
    c = load_vec3(a, y, x)  # every tap is clamped into the image: the unchecked loads (kernels/load.py)
    a00 = load_vec3(a, ym, xm)
    a01 = load_vec3(a, ym, x)
    a02 = load_vec3(a, ym, xp)
    a10 = load_vec3(a, y, xm)
    a12 = load_vec3(a, y, xp)
    a20 = load_vec3(a, yp, xm)
    a21 = load_vec3(a, yp, x)
    a22 = load_vec3(a, yp, xp)
    if a00 == c and a01 == c and a02 == c and a10 == c and a12 == c and a20 == c and a21 == c and a22 == c:
        return 0.0
    return sobel_max_channel(a00, a01, a02, a10, a12, a20, a21, a22)


@wp.func
def face_lab_at(face: wp.array2d(dtype=wp.int32), face_lab: wp.array(dtype=wp.vec3), x: int, y: int) -> wp.vec3:
    """CIE-Lab albedo of G-buffer entry (x, y) from the scene's per-face table (last entry: a miss)."""
    f = face[y, x]
    if f < 0:
        f = face_lab.shape[0] - 1
    return face_lab[f]


@wp.func
def sobel_lab_by_face(face: wp.array2d(dtype=wp.int32), face_lab: wp.array(dtype=wp.vec3), x: int, y: int) -> float:
    """Sobel magnitude (max over channels, edge-clamped) of the CIE-Lab albedo of a G-buffer, each tap looked up
    by its face in ``face_lab`` (``saliency.face_lab_kernel``: the same values as converting the albedo). Nine
    taps on one face (or all misses) read one table entry: the gradient is exactly 0 (see :func:`sobel_vec3`)."""
    if nine_equal_i32(face, y, x) != 0:  # the CPU's word compare of the same test (kernels/load.py)
        return 0.0
    xm, xp, ym, yp = clamped_neighbours(x, y, face.shape[1], face.shape[0])
    f = load_i32(face, y, x)  # clamped taps and table indices in [0, F]: the unchecked loads (kernels/load.py)
    f00 = load_i32(face, ym, xm)
    f01 = load_i32(face, ym, x)
    f02 = load_i32(face, ym, xp)
    f10 = load_i32(face, y, xm)
    f12 = load_i32(face, y, xp)
    f20 = load_i32(face, yp, xm)
    f21 = load_i32(face, yp, x)
    f22 = load_i32(face, yp, xp)
    if f00 == f and f01 == f and f02 == f and f10 == f and f12 == f and f20 == f and f21 == f and f22 == f:
        return 0.0
    n = face_lab.shape[0] - 1
    return sobel_max_channel(load1_vec3(face_lab, wp.where(f00 < 0, n, f00)),
                             load1_vec3(face_lab, wp.where(f01 < 0, n, f01)),
                             load1_vec3(face_lab, wp.where(f02 < 0, n, f02)),
                             load1_vec3(face_lab, wp.where(f10 < 0, n, f10)),
                             load1_vec3(face_lab, wp.where(f12 < 0, n, f12)),
                             load1_vec3(face_lab, wp.where(f20 < 0, n, f20)),
                             load1_vec3(face_lab, wp.where(f21 < 0, n, f21)),
                             load1_vec3(face_lab, wp.where(f22 < 0, n, f22)))


@wp.func
def dof_factor(depth: float, focus: float, sigma1: float, sigma2: float, dof_floor: float) -> float:
    """F_DoF: 1 while |depth - focus| <= sigma1, then linear down to ``dof_floor`` at sigma1 + sigma2 and
    ``dof_floor`` beyond (metres; sigma2 > 0 is validated by SaliencyConfig)."""
    t = wp.clamp((wp.abs(depth - focus) - sigma1) / sigma2, 0.0, 1.0)
    return 1.0 - (1.0 - dof_floor) * t


# -- kernels (the stage runs lab_kernel as a prepass, so each pixel is converted once, not once per
# neighbour; the fused sampling kernel calls sobel_vec3 and dof_factor; ops/tests run all of these) ----------


@wp.kernel(enable_backward=False)
def lab_kernel(albedo: wp.array2d(dtype=wp.vec3), out: wp.array2d(dtype=wp.vec3), row0: int):
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    out[y, x] = linear_rgb_to_lab(albedo[y, x])


@wp.kernel(enable_backward=False)
def face_lab_kernel(face_albedo: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
    """CIE-Lab of every face's albedo, ``out[f]`` for f < F, and of the miss albedo (black) in ``out[F]``
    (``out`` has F + 1 entries): read by the G-buffer's face index (:func:`face_lab_at`), the values
    ``lab_kernel`` computes from a scene's G-buffer albedo, without a cube root per pixel."""
    i = wp.tid()
    c = wp.vec3(0.0, 0.0, 0.0)
    if i < face_albedo.shape[0]:
        c = face_albedo[i]
    out[i] = linear_rgb_to_lab(c)


@wp.kernel(enable_backward=False)
def gradient_kernel(a: wp.array2d(dtype=wp.vec3), out: wp.array2d(dtype=float), row0: int):
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    out[y, x] = sobel_vec3(a, x, y)


@wp.kernel(enable_backward=False)
def dof_factor_kernel(depth: wp.array2d(dtype=float), focus: float, sigma1: float, sigma2: float, dof_floor: float,
                      out: wp.array2d(dtype=float),
                      row0: int,
):
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    out[y, x] = dof_factor(depth[y, x], focus, sigma1, sigma2, dof_floor)
