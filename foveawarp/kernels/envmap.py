"""An equirectangular HDR environment as a light: radiance lookup, importance sampling and pdf.

Mapping (Mitsuba 3's ``envmap`` emitter, so that one map lights a scene the same way in both renderers): a
direction ``d`` in the map's local frame (``to_local * d_world``) has

    u = atan2(d.x, -d.z) / (2 pi)  (wrapped into [0, 1)),   v = acos(d.y) / pi,
    d = (sin(2 pi u) sin(pi v), cos(pi v), -cos(2 pi u) sin(pi v)),

so the local +Y (v = 0) is the image's top row and -Z (u = 0) the left edge. The radiance is bilinear between
texel values placed at ``u = (i + 0.5) / W`` (column ``i``, periodic in u) and ``v = j / (H - 1)`` (row ``j``,
the first and last rows on the poles, clamped in v), times ``scale``: Mitsuba's ``eval``. Maps under 3 rows or
2 columns arrive padded as Mitsuba pads them (``foveawarp.envmap.pad_map``), so ``H >= 3`` and ``W >= 2`` here.

Sampling: the sphere is cut into cells between neighbouring texel positions, ``W`` columns of width
``2 pi / W`` (cell ``i`` spans ``u`` in ``[(i + 0.5) / W, (i + 1.5) / W)``, its corners columns ``i`` and
``i + 1 mod W``) times ``B = max(H - 1, 1)`` bands (band ``j`` spans ``theta`` in ``[pi j / B, pi (j + 1) / B]``,
its corners rows ``j`` and ``min(j + 1, H - 1)``). A cell's weight is the mean luminance of its four corner
texels (the integral of the bilinear luminance over the cell, per unit (u, v) area) times its solid angle
``(2 pi / W) (cos theta_j - cos theta_{j+1})``, so the density in (u, v) is the luminance times ``sin(theta)``;
within a cell the direction is uniform in solid angle (uniform in ``phi`` and in ``cos theta``). The pdf is
therefore piecewise constant in solid angle, ``pdf = mean luminance / sum over cells of (mean luminance x solid
angle)``, finite at the poles, positive wherever the looked-up radiance is, and exactly ``1 / (4 pi)`` for a
constant map. A map of zero luminance samples the sphere uniformly (its radiance is 0 anyway). The marginal CDF
over bands and one conditional CDF over columns per band are built on the host (``foveawarp.envmap``); a sample
picks a band with ``u2`` and a column with ``u1`` by binary search, then places the direction inside the cell
with the rescaled remainders of ``u1`` and ``u2``.

Every function here takes or returns WORLD directions except where named ``local``; invalid directions (zero
length, NaN, Inf) look up 0 radiance and have pdf 0, so no input gives NaN or Inf.
"""

import warp as wp

__all__ = [
    "LUMINANCE",
    "ONE_BELOW",
    "EnvironmentMap",
    "env_local_to_uv",
    "env_uv_to_local",
    "env_lookup_uv",
    "env_eval",
    "env_sample",
    "env_pdf",
    "env_eval_kernel",
    "env_sample_kernel",
    "env_pdf_kernel",
]

# Rec. 709 / sRGB luminance weights (those of Mitsuba's ``luminance``), for the sampling weights on the host
LUMINANCE = (0.212671, 0.715160, 0.072169)
# the largest float32 below 1: a uniform number is clamped to it so the CDF search never runs past the last cell
ONE_BELOW = wp.constant(0.99999994)
_PI = wp.constant(3.14159265358979)
_TWO_PI = wp.constant(6.28318530717959)


@wp.struct
class EnvironmentMap:
    """An environment's device data (built by ``foveawarp.envmap.Environment.to_device``).

    Attributes:
        texels: linear RGB radiance, ``height * width`` texels row-major, row 0 the image's top (local +Y).
        width, height: the map's size in texels (>= 1).
        num_bands: ``max(height - 1, 1)``, the sampling cells' rows.
        marginal_cdf: ``num_bands + 1`` values, 0 first and 1 last: the CDF over bands.
        conditional_cdf: per band ``width + 1`` values, 0 first and 1 last: the CDF over that band's columns.
        cell_pdf: per band and column (``band * width + column``), the solid-angle pdf of the cell's directions.
        to_world, to_local: the rotation from the map's frame to world space, and its transpose.
        scale: multiplies the radiance, >= 0.
        luminance_integral: the integral over the sphere of the luminance of the sampling weights, times
            ``scale`` (0 for a black map: a shading kernel may skip the light).
    """

    texels: wp.array(dtype=wp.vec3)
    width: int
    height: int
    num_bands: int
    marginal_cdf: wp.array(dtype=float)
    conditional_cdf: wp.array(dtype=float)
    cell_pdf: wp.array(dtype=float)
    to_world: wp.mat33
    to_local: wp.mat33
    scale: float
    luminance_integral: float


@wp.func
def env_local_to_uv(d: wp.vec3) -> wp.vec2:
    """(u, v) in ``[0, 1) x [0, 1]`` of a unit local direction (Mitsuba's ``direction_to_uv``, u wrapped)."""
    u = wp.atan2(d[0], -d[2]) / _TWO_PI
    u = u - wp.floor(u)
    if u >= 1.0:  # a tiny negative u rounds up to 1
        u = 0.0
    v = wp.acos(wp.clamp(d[1], -1.0, 1.0)) / _PI
    return wp.vec2(u, v)


@wp.func
def env_uv_to_local(uv: wp.vec2) -> wp.vec3:
    """The unit local direction of (u, v) (Mitsuba's ``uv_to_direction``)."""
    phi = _TWO_PI * uv[0]
    theta = _PI * uv[1]
    s = wp.sin(theta)
    return wp.vec3(wp.sin(phi) * s, wp.cos(theta), -wp.cos(phi) * s)


@wp.func
def _texel(env: EnvironmentMap, i: int, j: int) -> wp.vec3:
    return env.texels[j * env.width + i]


@wp.func
def env_lookup_uv(env: EnvironmentMap, uv: wp.vec2) -> wp.vec3:
    """Scaled radiance at (u, v): bilinear, periodic in u around texel centres ``(i + 0.5) / W``, rows at
    ``v = j / (H - 1)`` clamped in v."""
    w = env.width
    h = env.height
    u = uv[0] - wp.floor(uv[0])
    v = wp.clamp(uv[1], 0.0, 1.0)
    x = u * float(w) - 0.5
    fx = wp.floor(x)
    ax = x - fx
    i0 = int(fx)
    if i0 < 0:
        i0 += w
    if i0 >= w:
        i0 -= w
    i1 = i0 + 1
    if i1 >= w:
        i1 = 0
    y = v * float(h - 1)
    fy = wp.floor(y)
    ay = y - fy
    j0 = wp.clamp(int(fy), 0, h - 1)
    j1 = wp.min(j0 + 1, h - 1)
    top = (1.0 - ax) * _texel(env, i0, j0) + ax * _texel(env, i1, j0)
    bottom = (1.0 - ax) * _texel(env, i0, j1) + ax * _texel(env, i1, j1)
    return env.scale * ((1.0 - ay) * top + ay * bottom)


@wp.func
def _to_local_unit(env: EnvironmentMap, d: wp.vec3) -> wp.vec4:
    """(local unit direction, 1) of a world direction, or (0, 0, 0, 0) for a zero, NaN or Inf one."""
    n = wp.length(d)
    if not (n > 0.0) or not wp.isfinite(n):
        return wp.vec4(0.0, 0.0, 0.0, 0.0)
    l = env.to_local * (d / n)
    return wp.vec4(l[0], l[1], l[2], 1.0)


@wp.func
def env_eval(env: EnvironmentMap, direction: wp.vec3) -> wp.vec3:
    """Radiance arriving from world ``direction`` (the direction a missed ray travels), scaled; 0 for an invalid
    direction."""
    l = _to_local_unit(env, direction)
    if l[3] == 0.0:
        return wp.vec3(0.0, 0.0, 0.0)
    return env_lookup_uv(env, env_local_to_uv(wp.vec3(l[0], l[1], l[2])))


@wp.func
def _search(cdf: wp.array(dtype=float), start: int, n: int, x: float) -> int:
    """The largest ``k`` in ``[0, n - 1]`` with ``cdf[start + k] <= x`` (for x below ``cdf[start + n]``, the cell
    ``k`` then has ``cdf[start + k] <= x < cdf[start + k + 1]``, so a cell of zero probability is never chosen)."""
    lo = int(0)
    hi = n - 1
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if cdf[start + mid] <= x:
            lo = mid
        else:
            hi = mid - 1
    return lo


@wp.func
def _unit_interval(x: float) -> float:
    """``x`` clamped to ``[0, ONE_BELOW]``; NaN gives 0."""
    if not (x >= 0.0):
        return 0.0
    return wp.min(x, ONE_BELOW)


@wp.func
def _remainder(x: float, lo: float, hi: float) -> float:
    """Where ``x`` lies in ``[lo, hi)``, in [0, 1]."""
    span = hi - lo
    if span > 0.0:
        return wp.clamp((x - lo) / span, 0.0, 1.0)
    return 0.5


@wp.func
def env_sample(env: EnvironmentMap, u1: float, u2: float):
    """A direction drawn from the environment's importance distribution with uniform numbers ``u1`` (column) and
    ``u2`` (band) in [0, 1) -> (world direction (unit), scaled radiance from it, solid-angle pdf)."""
    w = env.width
    b = env.num_bands
    x2 = _unit_interval(u2)
    j = _search(env.marginal_cdf, 0, b, x2)
    t2 = _remainder(x2, env.marginal_cdf[j], env.marginal_cdf[j + 1])
    x1 = _unit_interval(u1)
    row = j * (w + 1)
    i = _search(env.conditional_cdf, row, w, x1)
    t1 = _remainder(x1, env.conditional_cdf[row + i], env.conditional_cdf[row + i + 1])
    # uniform in phi across the cell, uniform in cos(theta) across the band
    u = (float(i) + 0.5 + t1) / float(w)
    u = u - wp.floor(u)
    c0 = wp.cos(_PI * float(j) / float(b))
    c1 = wp.cos(_PI * float(j + 1) / float(b))
    cos_t = wp.clamp(c0 - t2 * (c0 - c1), -1.0, 1.0)
    sin_t = wp.sqrt(wp.max(0.0, 1.0 - cos_t * cos_t))
    phi = _TWO_PI * u
    local = wp.vec3(wp.sin(phi) * sin_t, cos_t, -wp.cos(phi) * sin_t)
    radiance = env_lookup_uv(env, wp.vec2(u, wp.acos(cos_t) / _PI))
    return env.to_world * local, radiance, env.cell_pdf[j * w + i]


@wp.func
def env_pdf(env: EnvironmentMap, direction: wp.vec3) -> float:
    """The solid-angle pdf with which :func:`env_sample` draws world ``direction``; 0 for an invalid one."""
    l = _to_local_unit(env, direction)
    if l[3] == 0.0:
        return 0.0
    w = env.width
    b = env.num_bands
    uv = env_local_to_uv(wp.vec3(l[0], l[1], l[2]))
    # columns start half a texel to the right of u = 0
    s = uv[0] * float(w) - 0.5
    i = int(wp.floor(s))
    if i < 0:
        i += w
    i = wp.clamp(i, 0, w - 1)
    j = wp.clamp(int(wp.floor(uv[1] * float(b))), 0, b - 1)
    return env.cell_pdf[j * w + i]


# ---------------------------------------------------------------------------------------------------------------
# kernels for host-side calls (foveawarp.envmap.Environment.eval / sample / pdf) and tests


@wp.kernel(enable_backward=False)
def env_eval_kernel(env: EnvironmentMap, direction: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = env_eval(env, direction[i])


@wp.kernel(enable_backward=False)
def env_sample_kernel(env: EnvironmentMap, u: wp.array(dtype=wp.vec2), direction: wp.array(dtype=wp.vec3),
                      radiance: wp.array(dtype=wp.vec3), pdf: wp.array(dtype=float)):
    i = wp.tid()
    d, r, p = env_sample(env, u[i][0], u[i][1])
    direction[i] = d
    radiance[i] = r
    pdf[i] = p


@wp.kernel(enable_backward=False)
def env_pdf_kernel(env: EnvironmentMap, direction: wp.array(dtype=wp.vec3), out: wp.array(dtype=float)):
    i = wp.tid()
    out[i] = env_pdf(env, direction[i])
