"""One-bounce diffuse indirect light from a light quad-tree over a reflective shadow map (Ki & Oh;
ALGORITHMS.md C). Kernels only; ``stages/indirect.py`` owns the buffers and the launch order.

Storage. The quad-tree is one flat array per quantity holding every level, coarsest first: level ``L`` has
``2^L x 2^L`` nodes starting at ``level_offset(L) = (4^L - 1) / 3``, and within a level the nodes are in
Morton (Z) order, so the four children of node ``m`` of level ``L`` are ``4m .. 4m + 3`` of level ``L + 1``.
The leaf level ``log2(rsm_size)`` is the RSM itself: RSM texel (row i, column j) is leaf ``morton(i, j)``.

RSM. Texel (i, j) of the ``N x N`` map is the direction given by an EQUAL-AREA map of the square onto the
spot cone: the square [-1, 1]^2 -> unit disk by Shirley & Chiu's concentric map, then disk radius ``r`` ->
polar angle by ``cos(theta) = 1 - r^2 (1 - cos_outer)`` (Lambert's equal-area projection restricted to the
cap). Every texel therefore subtends the same solid angle ``2 pi (1 - cos_outer) / N^2``. A point light uses
the whole sphere (``cos_outer = -1``). Per texel the VPL stores
``flux = intensity * spot_factor(direction) * solid_angle * albedo(hit face)`` (albedo IS in the flux: it is
the flux the surface reflects), the hit position, the normal facing the light, and the depth (distance from
the light). Misses store zero flux.

Pyramid. A node's flux is the SUM of its children's flux; position, normal and depth are averages weighted by
the children's scalar flux weight ``w = flux.r + flux.g + flux.b`` (the averaged normal is renormalized).
Zero-flux children (misses, black surfaces, outside the spot) emit nothing: they get weight 0 in the averages
and are ignored by the similarity tests. A node is VALID when every child of non-zero weight is close to the
average (``|depth_c - depth_avg| < depth_tol`` and ``dot(n_c, n_avg) > normal_threshold``) AND every child is
itself valid; single VPLs (leaves) and all-zero nodes are valid. The second condition makes validity monotone
(a valid cluster never hides an invalid sub-cluster), so the paper's per-level rule "a node contributes when
it is valid (or on the limit level) and its parent is not" selects exactly the nodes a top-down descent stops
at: a partition of the VPLs.

Extent. Every node also stores ``spread2``, the flux-weighted mean squared distance of its VPLs from its
centre, and ``radius``, a sphere about the centre holding all of them (0 for a single VPL): from the
children's spheres in ``pyramid_level_kernel``, then, for the levels the gather uses (start level and
finer), the exact largest distance of a lit VPL from the centre (``tight_radius_kernel``).
Packed nodes. The gather reads each node as three 16-byte words (``pack_nodes_kernel``): (centre, radius),
(flux, emitter a^2), (normal, valid); the cut list keeps them the same way. One visit of the
per-receiver descent is then three independent loads instead of a chain of seven.

Shading (RSM irradiance form, visibility ignored, ALGORITHMS.md C.4), for point VPLs ("exact", "sampled"):
``E(x) = 1/pi * sum_c Phi_c max(0, n_c.(x - x_c)) max(0, n.(x_c - x)) / max(|x - x_c|^2, d_min^2)^2`` and
``L = albedo / pi * E * strength``. The extra ``1/pi`` is the Lambertian VPL's radiant intensity ``Phi cos / pi``
(Dachsbacher & Stamminger's printed form folds it into Phi); with it, strength 1 is the physical unoccluded
one-bounce radiance, on the same scale as the direct term of ``shade.py``.
The tree methods evaluate a cluster as an EXTENDED emitter (``cluster_term``): the second
``max(|d|^2, d_min^2)`` of the denominator becomes ``max(|d|^2 + a^2, d_min^2)`` with
``a^2 = cluster_radius_scale^2 * spread2`` (a Lambertian disk's on-axis form, in the spirit of virtual
spherical lights): the point form for a single VPL, within ``a^2 / |d|^2`` of it far away, and at most
``Phi / max(a^2, d_min^2)`` on or inside the cluster, so a wide cluster is no point singularity.
Per-receiver refinement (Lightcuts-style, ``refine_budget > 0``): starting from the view-independent cut, a
cluster wider than ``refine_min_radius`` (a multiple of ``d_min``), seen under ``radius / distance >
refine_min_ratio``, whose estimated error at the receiver (``cluster_error``: the strict bound
``cluster_bound`` times ``min(1, radius / gap)^2``) exceeds ``refine_threshold`` times the receiver's coarse
estimate (``split_threshold``) is replaced by its four children, recursively, until the receiver's budget of
splits is spent (``wants_split``).
"""

import warp as wp

from .gbuffer import pixel_albedo, shading_normal
from .rng import onb_from
from .shade import LightParams, list_pixel, spot_factor
from .surface import SurfaceData, eval_surface_at


@wp.struct
class IndirectParams:
    """Everything the indirect gather reads: the quad-tree (per-receiver traversal) or a flat VPL list
    (the light cut, all VPLs, or the sampled VPLs) and the shading constants."""

    tree_flux: wp.array(dtype=wp.vec3)
    tree_pos: wp.array(dtype=wp.vec3)
    tree_normal: wp.array(dtype=wp.vec3)
    tree_valid: wp.array(dtype=wp.uint8)
    tree_spread2: wp.array(dtype=float)  # flux-weighted mean squared distance of the VPLs from the node centre
    tree_radius: wp.array(dtype=float)  # radius of a sphere about the node centre holding all its VPLs
    list_flux: wp.array(dtype=wp.vec3)
    list_pos: wp.array(dtype=wp.vec3)
    list_normal: wp.array(dtype=wp.vec3)
    list_spread2: wp.array(dtype=float)
    list_node: wp.array(dtype=wp.int32)  # flat pyramid index of each list entry ("lighttree" only)
    node_a: wp.array(dtype=wp.vec4)  # tree methods, per pyramid node: (centre, bounding radius)
    node_b: wp.array(dtype=wp.vec4)  # (flux, emitter a^2 = radius_scale2 x spread2)
    node_c: wp.array(dtype=wp.vec4)  # (normal, 1 when valid else 0)
    cut_a: wp.array(dtype=wp.vec4)  # "lighttree": the cut's entries, packed as node_a / node_b / node_c
    cut_b: wp.array(dtype=wp.vec4)
    cut_c: wp.array(dtype=wp.vec4)
    list_count: wp.array(dtype=wp.int32)
    use_tree: int  # 1: descend the tree per receiver; 0: sum the list[0:list_count[0]]
    start_level: int
    limit_level: int
    leaf_level: int
    extended: int  # 1: clusters are extended emitters (tree methods); 0: point VPLs (exact, sampled)
    radius_scale2: float  # a^2 = radius_scale2 * spread2: the emitter's softening radius
    refine_threshold: float  # split a cluster when its error bound exceeds this fraction of the estimate
    refine_budget: int  # splits per receiver; 0: no refinement
    refine_ratio2: float  # only clusters seen under (radius / distance)^2 above this are tested for a split
    refine_min_radius: float  # clusters of a bounding radius at or below this (world units) are never split
    floor_per_flux: float  # estimates below floor_per_flux * (total flux) count as that in the split threshold
    d_min2: float  # squared distance clamp, > 0
    scale: float  # strength / pi^2 (albedo / pi times the VPL's 1 / pi)
    enabled: int  # 0: nothing to add (no light)


# ---------------------------------------------------------------------------------------------------
# indexing


@wp.func
def part1by1(v: int) -> int:
    """Spread the low 16 bits of v to the even bit positions."""
    x = v & 0x0000FFFF
    x = (x | (x << 8)) & 0x00FF00FF
    x = (x | (x << 4)) & 0x0F0F0F0F
    x = (x | (x << 2)) & 0x33333333
    x = (x | (x << 1)) & 0x55555555
    return x


@wp.func
def morton2(row: int, col: int) -> int:
    """Morton index of (row, col): column bits on even positions, row bits on odd positions."""
    return part1by1(col) | (part1by1(row) << 1)


@wp.func
def level_offset(level: int) -> int:
    """First index of ``level`` in the flat pyramid: (4^L - 1) / 3."""
    return ((1 << (2 * level)) - 1) // 3


@wp.func
def flux_weight(f: wp.vec3) -> float:
    return f[0] + f[1] + f[2]


# ---------------------------------------------------------------------------------------------------
# RSM


@wp.func
def concentric_disk(u: float, v: float) -> wp.vec2:
    """Shirley & Chiu's area-preserving map of the square [-1, 1]^2 onto the unit disk."""
    if u == 0.0 and v == 0.0:
        return wp.vec2(0.0, 0.0)
    r = float(0.0)
    phi = float(0.0)
    if wp.abs(u) > wp.abs(v):
        r = u
        phi = (wp.pi / 4.0) * (v / u)
    else:
        r = v
        phi = (wp.pi / 2.0) - (wp.pi / 4.0) * (u / v)
    return wp.vec2(r * wp.cos(phi), r * wp.sin(phi))


@wp.func
def cone_direction(axis: wp.vec3, cos_outer: float, u: float, v: float) -> wp.vec3:
    """Unit direction of square coordinates (u, v) in [-1, 1]^2 under the equal-area square -> cone map."""
    d = concentric_disk(u, v)
    r2 = d[0] * d[0] + d[1] * d[1]
    cos_t = wp.clamp(1.0 - r2 * (1.0 - cos_outer), -1.0, 1.0)
    sin_t = wp.sqrt(wp.max(0.0, 1.0 - cos_t * cos_t))
    r = wp.sqrt(r2)
    a = float(0.0)
    b = float(0.0)
    if r > 1.0e-20:
        a = sin_t * d[0] / r
        b = sin_t * d[1] / r
    return wp.normalize(onb_from(axis, a, b, cos_t))


def _make_rsm(textured: bool):
    """The RSM trace for untextured scenes (each VPL's albedo its face's colour) or, with ``textured``, for scenes
    with materials (the base colour of the hit's material and texture at the finest level): one body, the
    textured part selected at code generation."""
    suffix = "_textured" if textured else ""

    @wp.kernel(enable_backward=False, name=f"rsm{suffix}_kernel")
    def rsm_kernel(
        mesh: wp.uint64,
        indices: wp.array(dtype=wp.int32),
        vnormals: wp.array(dtype=wp.vec3),
        smooth: wp.array(dtype=wp.uint8),
        face_albedo: wp.array(dtype=wp.vec3),
        sd: SurfaceData,
        l: LightParams,
        size: int,
        max_t: float,
        out_flux: wp.array(dtype=wp.vec3),
        out_pos: wp.array(dtype=wp.vec3),
        out_normal: wp.array(dtype=wp.vec3),
        out_depth: wp.array(dtype=float),
        out_valid: wp.array(dtype=wp.uint8),
        out_spread2: wp.array(dtype=float),
        out_radius: wp.array(dtype=float),
        row0: int,
    ):
        """Trace one VPL per texel (row i, column j) into the leaf level (Morton order)."""
        i, j = wp.tid()
        i += row0  # band offset (foveawarp.parallel)
        cos_outer = float(-1.0)  # point light: the whole sphere
        if l.kind == 1:
            cos_outer = wp.clamp(l.cos_outer, -1.0, 1.0)
        solid_angle = 2.0 * wp.pi * (1.0 - cos_outer) / float(size * size)
        inv = 2.0 / float(size)
        u = (float(j) + 0.5) * inv - 1.0
        v = (float(i) + 0.5) * inv - 1.0
        axis = l.direction
        la = wp.length(axis)
        if la > 1.0e-20:
            axis = axis / la
        else:
            axis = wp.vec3(0.0, -1.0, 0.0)
        d = cone_direction(axis, cos_outer, u, v)
        k = morton2(i, j)
        flux = wp.vec3(0.0, 0.0, 0.0)
        p = l.position
        n = wp.vec3(0.0, 0.0, 0.0)
        depth = float(0.0)
        q = wp.mesh_query_ray(mesh, l.position, d, max_t)
        if q.result:
            fn = q.normal
            if wp.dot(fn, d) > 0.0:
                fn = -fn  # face the light
            n = shading_normal(mesh, q.face, q.u, q.v, fn, vnormals, smooth, indices)
            p = l.position + d * q.t
            depth = q.t
            e = l.intensity * (spot_factor(l, d) * solid_angle)
            alb = face_albedo[q.face]
            if wp.static(textured):
                alb = eval_surface_at(sd, q.face, q.u, q.v, d, q.normal, -128.0).base_color
            flux = wp.cw_mul(e, alb)
        out_flux[k] = flux
        out_pos[k] = p
        out_normal[k] = n
        out_depth[k] = depth
        out_valid[k] = wp.uint8(1)  # single VPLs are always valid
        out_spread2[k] = 0.0  # a single VPL is a point
        out_radius[k] = 0.0

    return rsm_kernel


rsm_kernel = _make_rsm(False)
rsm_textured_kernel = _make_rsm(True)


# ---------------------------------------------------------------------------------------------------
# pyramid


@wp.kernel(enable_backward=False)
def pyramid_level_kernel(
    c_flux: wp.array(dtype=wp.vec3),
    c_pos: wp.array(dtype=wp.vec3),
    c_normal: wp.array(dtype=wp.vec3),
    c_depth: wp.array(dtype=float),
    c_valid: wp.array(dtype=wp.uint8),
    c_spread2: wp.array(dtype=float),
    c_radius: wp.array(dtype=float),
    depth_tol: float,
    normal_threshold: float,
    p_flux: wp.array(dtype=wp.vec3),
    p_pos: wp.array(dtype=wp.vec3),
    p_normal: wp.array(dtype=wp.vec3),
    p_depth: wp.array(dtype=float),
    p_valid: wp.array(dtype=wp.uint8),
    p_spread2: wp.array(dtype=float),
    p_radius: wp.array(dtype=float),
):
    """One level of the light quad-tree from the level below (children 4m .. 4m + 3).

    Extent: ``spread2`` is the flux-weighted mean of ``|x_vpl - x_node|^2`` over the node's VPLs (from the
    children's: ``sum w_c (spread2_c + |x_c - x_node|^2) / sum w_c``); ``radius`` bounds ``|x_vpl - x_node|``
    (``max_c |x_c - x_node| + radius_c``). Zero-flux children do not count."""
    m = wp.tid()
    c0 = 4 * m
    fsum = wp.vec3(0.0, 0.0, 0.0)
    wsum = float(0.0)
    psum = wp.vec3(0.0, 0.0, 0.0)
    nsum = wp.vec3(0.0, 0.0, 0.0)
    dsum = float(0.0)
    kids_valid = int(1)
    for k in range(4):
        f = c_flux[c0 + k]
        w = flux_weight(f)
        fsum += f
        if c_valid[c0 + k] == wp.uint8(0):
            kids_valid = 0
        if w > 0.0:
            wsum += w
            psum += c_pos[c0 + k] * w
            nsum += c_normal[c0 + k] * w
            dsum += c_depth[c0 + k] * w
    valid = int(1)
    pos = wp.vec3(0.0, 0.0, 0.0)
    nrm = wp.vec3(0.0, 0.0, 0.0)
    depth = float(0.0)
    spread2 = float(0.0)
    radius = float(0.0)
    if wsum > 0.0:
        pos = psum / wsum
        depth = dsum / wsum
        ln = wp.length(nsum)
        if ln > 1.0e-30:
            nrm = nsum / ln
        valid = kids_valid
        for k in range(4):
            if flux_weight(c_flux[c0 + k]) > 0.0:
                if not (wp.abs(c_depth[c0 + k] - depth) < depth_tol):
                    valid = 0
                if not (wp.dot(c_normal[c0 + k], nrm) > normal_threshold):
                    valid = 0
        s2 = float(0.0)
        for k in range(4):
            w = flux_weight(c_flux[c0 + k])
            if w > 0.0:
                dc = c_pos[c0 + k] - pos
                lc2 = wp.dot(dc, dc)
                s2 += w * (c_spread2[c0 + k] + lc2)
                radius = wp.max(radius, wp.sqrt(lc2) + c_radius[c0 + k])
        spread2 = s2 / wsum
    else:
        fsum = wp.vec3(0.0, 0.0, 0.0)
    p_flux[m] = fsum
    p_pos[m] = pos
    p_normal[m] = nrm
    p_depth[m] = depth
    p_valid[m] = wp.uint8(valid)
    p_spread2[m] = spread2
    p_radius[m] = radius


@wp.kernel(enable_backward=False)
def tight_radius_kernel(
    flux: wp.array(dtype=wp.vec3),
    pos: wp.array(dtype=wp.vec3),
    min_level: int,
    leaf_level: int,
    radius: wp.array(dtype=float),
):
    """The exact bounding radius ``max |x_vpl - x_node|`` over each node's emitting VPLs, for the nodes of levels
    ``min_level .. leaf_level - 1`` (zeroed before): one thread per leaf, an atomic max into each ancestor.
    The children-sphere bound of ``pyramid_level_kernel`` loosens with every level (at RSM 512^2 its median
    at level 7 is 1.5x the 256^2 one for the same texels' worth of surface); this one does not."""
    k = wp.tid()
    leaf = level_offset(leaf_level) + k
    if flux_weight(flux[leaf]) <= 0.0:
        return
    p = pos[leaf]
    for lv in range(min_level, leaf_level):
        node = level_offset(lv) + (k >> (2 * (leaf_level - lv)))
        wp.atomic_max(radius, node, wp.length(p - pos[node]))


@wp.kernel(enable_backward=False)
def pack_nodes_kernel(
    flux: wp.array(dtype=wp.vec3),
    pos: wp.array(dtype=wp.vec3),
    normal: wp.array(dtype=wp.vec3),
    valid: wp.array(dtype=wp.uint8),
    spread2: wp.array(dtype=float),
    radius: wp.array(dtype=float),
    radius_scale2: float,
    out_a: wp.array(dtype=wp.vec4),
    out_b: wp.array(dtype=wp.vec4),
    out_c: wp.array(dtype=wp.vec4),
):
    """The gather's view of every pyramid node in three 16-byte words (one load each, issued together):
    a = (centre, bounding radius), b = (flux, emitter a^2), c = (normal, valid)."""
    k = wp.tid()
    p = pos[k]
    f = flux[k]
    nn = normal[k]
    v = float(0.0)
    if valid[k] != wp.uint8(0):
        v = 1.0
    out_a[k] = wp.vec4(p[0], p[1], p[2], radius[k])
    out_b[k] = wp.vec4(f[0], f[1], f[2], radius_scale2 * spread2[k])
    out_c[k] = wp.vec4(nn[0], nn[1], nn[2], v)


# ---------------------------------------------------------------------------------------------------
# the light cut (view independent: the same cluster set for every receiver)


@wp.func
def node_contributes(valid: wp.array(dtype=wp.uint8), flux: wp.array(dtype=wp.vec3), level: int, m: int,
                     start_level: int, limit_level: int) -> int:
    """1 when node m of ``level`` is a cluster of the cut: valid (or on the limit level), its parent not
    valid (or the node is on the start level), and it emits something."""
    node = level_offset(level) + m
    if flux_weight(flux[node]) <= 0.0:
        return 0
    if level != limit_level and valid[node] == wp.uint8(0):
        return 0
    if level > start_level:
        if valid[level_offset(level - 1) + (m >> 2)] != wp.uint8(0):
            return 0
    return 1


@wp.kernel(enable_backward=False)
def cut_flags_kernel(
    valid: wp.array(dtype=wp.uint8),
    flux: wp.array(dtype=wp.vec3),
    start_level: int,
    limit_level: int,
    flags: wp.array(dtype=wp.int32),
):
    """flags[g] for the nodes of levels start..limit, g = node - level_offset(start_level)."""
    g = wp.tid()
    node = level_offset(start_level) + g
    level = start_level
    while level < limit_level and node >= level_offset(level + 1):
        level += 1
    flags[g] = node_contributes(valid, flux, level, node - level_offset(level), start_level, limit_level)


@wp.kernel(enable_backward=False)
def cut_scatter_kernel(
    flags: wp.array(dtype=wp.int32),
    slots: wp.array(dtype=wp.int32),  # exclusive prefix sum of flags
    base: int,  # level_offset(start_level)
    flux: wp.array(dtype=wp.vec3),
    pos: wp.array(dtype=wp.vec3),
    normal: wp.array(dtype=wp.vec3),
    spread2: wp.array(dtype=float),
    node_a: wp.array(dtype=wp.vec4),
    node_b: wp.array(dtype=wp.vec4),
    node_c: wp.array(dtype=wp.vec4),
    out_flux: wp.array(dtype=wp.vec3),
    out_pos: wp.array(dtype=wp.vec3),
    out_normal: wp.array(dtype=wp.vec3),
    out_spread2: wp.array(dtype=float),
    out_node: wp.array(dtype=wp.int32),
    out_a: wp.array(dtype=wp.vec4),
    out_b: wp.array(dtype=wp.vec4),
    out_c: wp.array(dtype=wp.vec4),
    out_count: wp.array(dtype=wp.int32),
):
    g = wp.tid()
    n = flags.shape[0]
    cap = out_flux.shape[0]  # >= 4^limit, which bounds any cut; the guard only protects memory
    if g == n - 1:
        out_count[0] = wp.min(slots[g] + flags[g], cap)
    if flags[g] != 0 and slots[g] < cap:
        s = slots[g]
        out_flux[s] = flux[base + g]
        out_pos[s] = pos[base + g]
        out_normal[s] = normal[base + g]
        out_spread2[s] = spread2[base + g]
        out_node[s] = base + g
        out_a[s] = node_a[base + g]
        out_b[s] = node_b[base + g]
        out_c[s] = node_c[base + g]


@wp.kernel(enable_backward=False)
def gather_samples_kernel(
    texels: wp.array(dtype=wp.int32),  # Morton indices into the leaf level
    weight: float,
    leaf_flux: wp.array(dtype=wp.vec3),
    leaf_pos: wp.array(dtype=wp.vec3),
    leaf_normal: wp.array(dtype=wp.vec3),
    out_flux: wp.array(dtype=wp.vec3),
    out_pos: wp.array(dtype=wp.vec3),
    out_normal: wp.array(dtype=wp.vec3),
):
    """The sampled-RSM VPL list: each sample stands for ``weight`` = N^2 / samples VPLs."""
    k = wp.tid()
    t = texels[k]
    out_flux[k] = leaf_flux[t] * weight
    out_pos[k] = leaf_pos[t]
    out_normal[k] = leaf_normal[t]


# ---------------------------------------------------------------------------------------------------
# gather


@wp.func
def vpl_term(x: wp.vec3, n: wp.vec3, flux: wp.vec3, xp: wp.vec3, np_: wp.vec3, d_min2: float) -> wp.vec3:
    """Phi max(0, n_p.(x - x_p)) max(0, n.(x_p - x)) / max(|x - x_p|^2, d_min^2)^2 (without the 1/pi)."""
    d = x - xp
    ce = wp.dot(np_, d)
    cr = -wp.dot(n, d)
    if ce <= 0.0 or cr <= 0.0:
        return wp.vec3(0.0, 0.0, 0.0)
    r2 = wp.max(wp.dot(d, d), d_min2)
    return flux * (ce * cr / (r2 * r2))


@wp.func
def cluster_term(x: wp.vec3, n: wp.vec3, flux: wp.vec3, xp: wp.vec3, np_: wp.vec3, a2: float,
                 d_min2: float) -> wp.vec3:
    """A cluster as an extended emitter of squared radius ``a2`` (without the 1/pi):
    ``Phi max(0, n_p.d) max(0, -n.d) / (max(|d|^2, d_min^2) max(|d|^2 + a^2, d_min^2))``, d = x - x_p.

    Far away (``|d|^2 >> a^2``) this is ``Phi cos_p cos / (|d|^2 + a^2)``, the on-axis irradiance of a
    Lambertian disk of radius ``a`` (``a^2 = 2 x`` the disk's mean squared radius); it is the point form
    ``vpl_term`` exactly when ``a2 = 0``, within a relative ``a^2 / |d|^2`` beyond ``d_min``, and never above
    ``Phi / max(a^2, d_min^2)`` (``cos_p cos |d|^2 <= |d|^2``): a receiver on or inside the cluster sees no
    point singularity."""
    d = x - xp
    return cluster_term_d(d, wp.dot(d, d), n, flux, np_, a2, d_min2)


@wp.func
def cluster_term_d(d: wp.vec3, r2: float, n: wp.vec3, flux: wp.vec3, np_: wp.vec3, a2: float,
                   d_min2: float) -> wp.vec3:
    """``cluster_term`` from the receiver offset ``d = x - x_p`` and ``r2 = |d|^2`` (already at hand in the
    gather)."""
    ce = wp.dot(np_, d)
    cr = -wp.dot(n, d)
    if ce <= 0.0 or cr <= 0.0:
        return wp.vec3(0.0, 0.0, 0.0)
    return flux * (ce * cr / (wp.max(r2, d_min2) * wp.max(r2 + a2, d_min2)))


@wp.func
def cluster_bound(x: wp.vec3, n: wp.vec3, w: float, c: wp.vec3, radius: float, d_min2: float) -> float:
    """Upper bound (in flux-weight units, the sum of the colour channels) of both a cluster's exact VPL sum
    and its ``cluster_term`` at the receiver (x, n): ``w / max(gap^2, d_min^2)``, ``gap = max(|c - x| - radius,
    0)`` the nearest the cluster's bounding sphere comes, and 0 when the sphere lies behind the receiver's plane
    (every term is at most ``Phi cos / max(d^2, d_min^2)``). Both sums lie in [0, bound], so it also bounds the
    error of using the cluster (Lightcuts' rule)."""
    d = c - x
    if wp.dot(n, d) + radius <= 0.0:
        return 0.0
    g = wp.max(wp.length(d) - radius, 0.0)
    return w / wp.max(g * g, d_min2)


@wp.func
def cluster_error_d(e: wp.vec3, r2: float, n: wp.vec3, w: float, radius: float, d_min2: float) -> float:
    """``cluster_error`` from ``e = c - x`` and ``r2 = |e|^2``."""
    if wp.dot(n, e) + radius <= 0.0:
        return 0.0
    gap = wp.max(wp.sqrt(r2) - radius, wp.sqrt(d_min2))
    q = wp.min(1.0, radius / gap)
    return w / (gap * gap) * (q * q)


@wp.func
def cluster_error(x: wp.vec3, n: wp.vec3, w: float, c: wp.vec3, radius: float, d_min2: float) -> float:
    """Second-order estimate of the error of using the cluster at (x, n): ``cluster_bound`` times
    ``min(1, radius / gap)^2``, ``gap = max(|c - x| - radius, d_min)``. The cluster sits at its VPLs'
    flux-weighted centre, so the first-order terms of the VPL sum about that centre cancel and what is left
    of the error is ``O((radius / gap)^2)`` of the cluster's contribution: a far cluster is split only when it
    is both bright and wide; a receiver inside the sphere gets the full bound (the refinement's split rule).
    (A first-order ``radius / gap`` rule split about 15% more clusters on cornell for the same error.)"""
    e = c - x
    return cluster_error_d(e, wp.dot(e, e), n, w, radius, d_min2)


@wp.func
def may_split(x: wp.vec3, c: wp.vec3, radius: float, ratio2: float) -> int:
    """1 when the cluster's bounding sphere is seen under ``radius / distance > sqrt(ratio2)`` (no square
    root): only such clusters are tested for a split."""
    d = c - x
    if radius * radius > ratio2 * wp.dot(d, d):
        return 1
    return 0


@wp.func
def node_level(node: int) -> int:
    level = int(0)
    while node >= level_offset(level + 1):
        level += 1
    return level


@wp.func
def packed_term(d: wp.vec3, r2: float, n: wp.vec3, b: wp.vec4, np_: wp.vec3, d_min2: float) -> wp.vec3:
    """``cluster_term_d`` of a packed node (b = (flux, a^2))."""
    return cluster_term_d(d, r2, n, wp.vec3(b[0], b[1], b[2]), np_, b[3], d_min2)


@wp.func
def wants_split(ip: IndirectParams, x: wp.vec3, n: wp.vec3, d: wp.vec3, r2: float, w: float, radius: float,
                thr: float) -> int:
    """The split rule for a cluster of bounding ``radius`` and flux weight ``w`` at offset ``d = x - c``
    (``r2 = |d|^2``): wider than ``refine_min_radius``, seen under ``radius / distance > refine_min_ratio``
    (``may_split``), and its ``cluster_error`` above ``thr``."""
    if radius <= ip.refine_min_radius:
        return 0
    if radius * radius <= ip.refine_ratio2 * r2:
        return 0
    if cluster_error_d(-d, r2, n, w, radius, ip.d_min2) > thr:
        return 1
    return 0


@wp.func
def node_term(ip: IndirectParams, x: wp.vec3, n: wp.vec3, node: int) -> wp.vec3:
    a = ip.node_a[node]
    c = ip.node_c[node]
    d = x - wp.vec3(a[0], a[1], a[2])
    return packed_term(d, wp.dot(d, d), n, ip.node_b[node], wp.vec3(c[0], c[1], c[2]), ip.d_min2)


@wp.func
def descend(ip: IndirectParams, x: wp.vec3, n: wp.vec3, root_level: int, root_m: int, thr: float,
            budget: int) -> wp.vec4:
    """Sum of the subtree of node ``root_m`` of ``root_level`` as a stackless depth-first descent in Morton
    order. A node is opened when it is not a cluster of the view-independent cut (invalid above the limit
    level) or, with ``budget`` left and above the leaves, when the split rule (``wants_split``) holds (each
    such split spends 1 of ``budget``); otherwise it is added as an extended emitter. Each visit reads the
    node's three packed words (``pack_nodes_kernel``) at once. Returns (sum, budget left)."""
    acc = wp.vec3(0.0, 0.0, 0.0)
    level = root_level
    m = root_m
    done = int(0)
    while done == 0:
        node = level_offset(level) + m
        na = ip.node_a[node]
        nb = ip.node_b[node]
        nc = ip.node_c[node]
        w = nb[0] + nb[1] + nb[2]
        open_ = int(0)
        if w > 0.0:
            d = x - wp.vec3(na[0], na[1], na[2])
            r2 = wp.dot(d, d)
            if level < ip.limit_level and nc[3] == 0.0:
                open_ = 1
            elif budget > 0 and level < ip.leaf_level:
                if wants_split(ip, x, n, d, r2, w, na[3], thr) != 0:
                    open_ = 1
                    budget -= 1
            if open_ == 0:
                acc += packed_term(d, r2, n, nb, wp.vec3(nc[0], nc[1], nc[2]), ip.d_min2)
        if open_ != 0:
            level += 1
            m = m * 4
        else:
            # next node: the next sibling, climbing while this was the last child
            m += 1
            while level > root_level and (m & 3) == 0:
                m = m >> 2
                level -= 1
            if level == root_level:
                done = 1
    return wp.vec4(acc[0], acc[1], acc[2], float(budget))


@wp.func
def split_threshold(ip: IndirectParams, x: wp.vec3, n: wp.vec3) -> float:
    """``refine_threshold x`` the receiver's coarse estimate: the nodes of level ``min(start_level, 2)`` (at
    most 16) as extended emitters, floored at ``floor_per_flux x`` the total flux."""
    lv = wp.min(ip.start_level, 2)
    e = wp.vec3(0.0, 0.0, 0.0)
    base = level_offset(lv)
    for m in range(1 << (2 * lv)):
        e += node_term(ip, x, n, base + m)  # (a zero-flux node adds 0)
    b0 = ip.node_b[0]
    est = wp.max(flux_weight(e), ip.floor_per_flux * (b0[0] + b0[1] + b0[2]))
    return ip.refine_threshold * est


@wp.func
def gather_list(ip: IndirectParams, x: wp.vec3, n: wp.vec3) -> wp.vec3:
    """Sum of the list: point VPLs (exact, sampled), or the cut's clusters as extended emitters, refined per
    receiver (Lightcuts-style) when ``refine_budget > 0``: in list order (coarse levels first), a cluster
    the split rule selects (``wants_split``: wide enough, seen under ``radius / distance > refine_min_ratio``,
    estimated error (``cluster_error``) above the split threshold (``split_threshold``)) is replaced by its
    subtree, itself refined by the same rule, until the receiver's budget of splits is spent."""
    acc = wp.vec3(0.0, 0.0, 0.0)
    count = ip.list_count[0]
    if ip.extended == 0:
        for k in range(count):
            acc += vpl_term(x, n, ip.list_flux[k], ip.list_pos[k], ip.list_normal[k], ip.d_min2)
        return acc
    budget = ip.refine_budget
    thr = float(0.0)
    if budget > 0:
        thr = split_threshold(ip, x, n)
    for k in range(count):
        ca = ip.cut_a[k]
        cb = ip.cut_b[k]
        cc = ip.cut_c[k]
        np_ = wp.vec3(cc[0], cc[1], cc[2])
        d = x - wp.vec3(ca[0], ca[1], ca[2])
        r2 = wp.dot(d, d)
        opened = int(0)
        if budget > 0:
            if wants_split(ip, x, n, d, r2, cb[0] + cb[1] + cb[2], ca[3], thr) != 0:
                node = ip.list_node[k]
                level = node_level(node)
                r = descend(ip, x, n, level, node - level_offset(level), thr, budget)
                budget = int(r[3])
                acc += wp.vec3(r[0], r[1], r[2])
                opened = 1
        if opened == 0:
            acc += packed_term(d, r2, n, cb, np_, ip.d_min2)
    return acc


@wp.func
def gather_tree(ip: IndirectParams, x: wp.vec3, n: wp.vec3) -> wp.vec3:
    """The paper's per-receiver traversal: a stackless Morton-order descent from every start-level node,
    stopping at valid or limit-level nodes (the paper's breadth-first passes select the same clusters); with
    ``refine_budget > 0`` the descent also opens clusters by the rule of ``gather_list`` (depth first, so a
    spent budget may leave different clusters unopened than the list order does)."""
    acc = wp.vec3(0.0, 0.0, 0.0)
    budget = ip.refine_budget
    thr = float(3.0e38)
    if budget > 0:
        thr = split_threshold(ip, x, n)
    for m in range(1 << (2 * ip.start_level)):
        r = descend(ip, x, n, ip.start_level, m, thr, budget)
        budget = int(r[3])
        acc += wp.vec3(r[0], r[1], r[2])
    return acc


@wp.func
def indirect_radiance(ip: IndirectParams, x: wp.vec3, n: wp.vec3, albedo: wp.vec3) -> wp.vec3:
    """albedo / pi * E(x) * strength at the receiver (x, n); zero for a zero normal."""
    if ip.enabled == 0:
        return wp.vec3(0.0, 0.0, 0.0)
    if wp.dot(n, n) == 0.0:
        return wp.vec3(0.0, 0.0, 0.0)
    e = wp.vec3(0.0, 0.0, 0.0)
    if ip.use_tree != 0:
        e = gather_tree(ip, x, n)
    else:
        e = gather_list(ip, x, n)
    return wp.cw_mul(albedo, e) * ip.scale


@wp.kernel(enable_backward=False)
def indirect_points_kernel(
    ip: IndirectParams,
    pos: wp.array(dtype=wp.vec3),
    normal: wp.array(dtype=wp.vec3),
    albedo: wp.array(dtype=wp.vec3),
    out: wp.array(dtype=wp.vec3),
    row0: int,
):
    """out[i] = indirect radiance at receiver i (overwrites)."""
    i = wp.tid()
    i += row0  # band offset (foveawarp.parallel)
    out[i] = indirect_radiance(ip, pos[i], normal[i], albedo[i])


@wp.kernel(enable_backward=False)
def indirect_full_kernel(
    ip: IndirectParams,
    pos: wp.array2d(dtype=wp.vec3),
    normal: wp.array2d(dtype=wp.vec3),
    face_albedo: wp.array(dtype=wp.vec3),
    face: wp.array2d(dtype=wp.int32),
    hit: wp.array2d(dtype=wp.uint8),
    textured: int,
    albedo: wp.array2d(dtype=wp.vec3),
    radiance: wp.array2d(dtype=wp.vec3),
    row0: int,
):
    """radiance[y, x] += indirect radiance at every hit pixel (its albedo: :func:`pixel_albedo`)."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    if hit[y, x] == wp.uint8(0):
        return
    radiance[y, x] = radiance[y, x] + indirect_radiance(ip, pos[y, x], normal[y, x],
                                                        pixel_albedo(textured, albedo, face_albedo, face, y, x))


@wp.kernel(enable_backward=False)
def indirect_list_kernel(
    ip: IndirectParams,
    work: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    width: int,
    pos: wp.array2d(dtype=wp.vec3),
    normal: wp.array2d(dtype=wp.vec3),
    face_albedo: wp.array(dtype=wp.vec3),
    face: wp.array2d(dtype=wp.int32),
    hit: wp.array2d(dtype=wp.uint8),
    textured: int,
    albedo: wp.array2d(dtype=wp.vec3),
    radiance: wp.array2d(dtype=wp.vec3),
    row0: int,
):
    """radiance at the flat pixel indices work[0:count[0]] (y * width + x) += indirect radiance."""
    i = wp.tid()
    i += row0  # band offset (foveawarp.parallel)
    if i >= count[0]:
        return
    x, y = list_pixel(work[i], width)
    if hit[y, x] == wp.uint8(0):
        return
    radiance[y, x] = radiance[y, x] + indirect_radiance(ip, pos[y, x], normal[y, x],
                                                        pixel_albedo(textured, albedo, face_albedo, face, y, x))
