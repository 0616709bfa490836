"""The textured surface at a ray hit: glTF 2.0 materials with their textures, cut-outs and culled back faces.

:class:`SurfaceData` bundles what a kernel needs to evaluate the material of any face of a textured scene
(``foveawarp.surface.surface_data`` fills it from a ``DeviceScene``): the mesh's indices and current positions,
the vertex normals, UV sets and tangents, the material table and the texture atlas (kernels/texture.py).

At a hit on face ``f`` with Warp's barycentrics ``(u, v)`` (the point is ``p0 u + p1 v + p2 (1 - u - v)``):

- the UVs of each texture slot are the slot's UV set interpolated, then its ``KHR_texture_transform``;
- the texture LOD of each slot is the ray cone's (kernels/texture.py: ``Delta`` of the slot's transformed UV
  triangle plus ``log2(W / |n . d|)`` of the cone), or level 0 with ``LOD_NONE``;
- base colour = ``base_color_factor`` x texture (linear RGBA); alpha = its A;
- metallic = factor x texture B, roughness = factor x texture G, occlusion = ``1 + strength (R - 1)``,
  emission = ``emissive_factor * strength`` x texture RGB;
- the shading normal: the interpolated vertex normals on smooth faces (else the face normal), then the normal map
  ``n = normalize(T x s + B y s + N z)`` with ``(x, y, z) = 2 texel - 1``, ``s`` = ``normal_scale``, in the frame
  of the vertex tangents (``B = w cross(N, T)``), or without tangents the face's own ``dP/du`` and the
  handedness of its UV triangle (so mirrored UVs flip ``B``); T is made orthogonal to N first. A map normal on
  the far side of the geometric normal falls back to the unmapped one.

Visibility (:func:`trace_surface`): primary rays pass through cut-outs (alpha mode MASK with alpha below the
cutoff; BLEND is treated as MASK at 0.5) and through back faces of single-sided materials (glTF's back-face
culling), up to :data:`MAX_LAYERS` skipped surfaces; :func:`surface_visible` lets shadow rays through cut-outs
(back faces cast shadows).
"""

import warp as wp

from .load import load1_i32, load1_u8, load1_vec3
from .texture import (LOD_NONE, TextureAtlas, cone_footprint_log2, cone_width, sample_texture,
                      triangle_uv_lod_delta)

# surfaces a ray may pass (cut-outs, culled back faces) before it counts as a miss (primary) or as blocked
# (shadow): 16 layers of foliage cards
MAX_LAYERS = wp.constant(16)
# material alpha modes (foveawarp.materials.ALPHA_MODES order) and texture slot columns (TEXTURE_SLOTS order)
ALPHA_OPAQUE = wp.constant(0)
ALPHA_MASK = wp.constant(1)
ALPHA_BLEND = wp.constant(2)
SLOT_BASE_COLOR = wp.constant(0)
SLOT_METALLIC_ROUGHNESS = wp.constant(1)
SLOT_NORMAL = wp.constant(2)
SLOT_OCCLUSION = wp.constant(3)
SLOT_EMISSIVE = wp.constant(4)
# UV triangles with |det| below this have no tangent frame of their own (the normal map is then not applied)
UV_DET_MIN = wp.constant(1.0e-20)


@wp.struct
class SurfaceData:
    """A textured scene's surface description on a device (see the module docstring).

    Attributes:
        indices, points: the mesh's vertex indices (3 per face) and current vertex positions.
        vnormals, smooth: vertex normals and the per-face 0/1 flag that interpolates them.
        uvs, uvs1: TEXCOORD_0 / TEXCOORD_1 per vertex (one unused entry where the scene has none).
        tangents: per vertex xyz tangent, w handedness; read only where ``has_tangents`` is 1.
        face_material: material index per face.
        base_color (vec4), metallic, roughness, normal_scale, occlusion_strength, alpha_cutoff, specular,
            emission (vec3), alpha_mode, double_sided, transmission, ior: per material; ``specular`` is the
            dielectric Fresnel scale of kernels/bsdf.py (1 for glTF's core material); ``transmission`` the glass
            part and ``ior`` its index of refraction (read by the path integrator only).
        texture: (M, 5) texture index per material and slot, -1 for none.
        tex_texcoord, tex_uv_linear, tex_uv_offset: per texture its UV set and UV transform.
        atlas: the textures (kernels/texture.py).
        lod_mode: ``LOD_NONE`` or ``LOD_RAY_CONE``.
        has_cutouts: 1 when some material is MASK or BLEND (0: the alpha test is skipped).
        ray_eps: the step past a skipped surface, world units.
    """

    indices: wp.array(dtype=wp.int32)
    points: wp.array(dtype=wp.vec3)
    vnormals: wp.array(dtype=wp.vec3)
    smooth: wp.array(dtype=wp.uint8)
    uvs: wp.array(dtype=wp.vec2)
    uvs1: wp.array(dtype=wp.vec2)
    tangents: wp.array(dtype=wp.vec4)
    has_tangents: int
    face_material: wp.array(dtype=wp.int32)
    base_color: wp.array(dtype=wp.vec4)
    metallic: wp.array(dtype=float)
    roughness: wp.array(dtype=float)
    normal_scale: wp.array(dtype=float)
    occlusion_strength: wp.array(dtype=float)
    alpha_cutoff: wp.array(dtype=float)
    specular: wp.array(dtype=float)
    emission: wp.array(dtype=wp.vec3)
    alpha_mode: wp.array(dtype=wp.int32)
    double_sided: wp.array(dtype=wp.int32)
    transmission: wp.array(dtype=float)
    ior: wp.array(dtype=float)
    texture: wp.array2d(dtype=wp.int32)
    tex_texcoord: wp.array(dtype=wp.int32)
    tex_uv_linear: wp.array(dtype=wp.mat22)
    tex_uv_offset: wp.array(dtype=wp.vec2)
    atlas: TextureAtlas
    lod_mode: int
    has_cutouts: int
    ray_eps: float


@wp.struct
class SurfacePoint:
    """The material at one hit: linear base colour and alpha, shading normal (unit, facing the viewer), glTF
    roughness and metallic, occlusion, emitted radiance, the dielectric Fresnel scale, and the glass part
    (``transmission``) with its index of refraction."""

    base_color: wp.vec3
    alpha: float
    normal: wp.vec3
    roughness: float
    metallic: float
    occlusion: float
    emission: wp.vec3
    specular: float
    transmission: float
    ior: float


@wp.struct
class SurfaceHit:
    """The closest visible hit of :func:`trace_surface`: ``result`` False on a miss; ``t`` along the unit ray from
    its origin, ``face``, barycentrics ``u``, ``v`` and the unit geometric normal ``normal`` (not turned)."""

    result: bool
    t: float
    face: int
    u: float
    v: float
    normal: wp.vec3


@wp.func
def _unit(x: float) -> float:
    """x clamped to [0, 1]; NaN gives 0."""
    if x > 1.0:
        return 1.0
    if x >= 0.0:
        return x
    return 0.0


@wp.func
def _finite3(a: wp.vec3) -> wp.vec3:
    """a with non-finite components set to 0."""
    r = a
    for k in range(3):
        if not wp.isfinite(a[k]):
            r[k] = 0.0
    return r


@wp.func
def vertex_uv(sd: SurfaceData, texcoord: int, i: int) -> wp.vec2:
    """UV set ``texcoord`` (0 or 1) of vertex ``i``."""
    if texcoord == 1:
        return sd.uvs1[i]
    return sd.uvs[i]


@wp.func
def slot_uvs(sd: SurfaceData, tex: int, i0: int, i1: int, i2: int):
    """The transformed UVs of texture ``tex`` at the three vertices of a face."""
    c = sd.tex_texcoord[tex]
    m = sd.tex_uv_linear[tex]
    o = sd.tex_uv_offset[tex]
    return m * vertex_uv(sd, c, i0) + o, m * vertex_uv(sd, c, i1) + o, m * vertex_uv(sd, c, i2) + o


@wp.func
def sample_slot(sd: SurfaceData, m: int, slot: int, i0: int, i1: int, i2: int, p0: wp.vec3, p1: wp.vec3,
                p2: wp.vec3, u: float, v: float, footprint_log2: float) -> wp.vec4:
    """Texture ``slot`` of material ``m`` at barycentrics (u, v) of the face (vertices i0, i1, i2 at p0, p1, p2)
    with the hit's cone footprint; white where the slot has no texture."""
    tex = sd.texture[m, slot]
    if tex < 0:
        return wp.vec4(1.0, 1.0, 1.0, 1.0)
    t0, t1, t2 = slot_uvs(sd, tex, i0, i1, i2)
    uv = t0 * u + t1 * v + t2 * (1.0 - u - v)
    delta = float(0.0)
    if sd.lod_mode != LOD_NONE:
        delta = triangle_uv_lod_delta(p0, p1, p2, t0, t1, t2)
    return sample_texture(sd.atlas, tex, uv, sd.lod_mode, delta, footprint_log2)


@wp.func
def cutoff_of(sd: SurfaceData, m: int) -> float:
    """The alpha below which material ``m`` is cut out: its cutoff (MASK), 0.5 (BLEND), 0 (OPAQUE: never)."""
    mode = sd.alpha_mode[m]
    if mode == ALPHA_MASK:
        return sd.alpha_cutoff[m]
    if mode == ALPHA_BLEND:
        return 0.5
    return 0.0


@wp.func
def hit_alpha(sd: SurfaceData, face: int, u: float, v: float, footprint_log2: float) -> float:
    """Base-colour alpha (factor x texture) at barycentrics (u, v) of ``face``."""
    m = sd.face_material[face]
    i0 = load1_i32(sd.indices, face * 3 + 0)
    i1 = load1_i32(sd.indices, face * 3 + 1)
    i2 = load1_i32(sd.indices, face * 3 + 2)
    a = sd.base_color[m][3]
    if sd.texture[m, SLOT_BASE_COLOR] >= 0:
        c = sample_slot(sd, m, SLOT_BASE_COLOR, i0, i1, i2, load1_vec3(sd.points, i0), load1_vec3(sd.points, i1),
                        load1_vec3(sd.points, i2), u, v, footprint_log2)
        a = a * c[3]
    return a


@wp.func
def is_cut_out(sd: SurfaceData, face: int, u: float, v: float, footprint_log2: float) -> bool:
    """Whether the hit at (u, v) of ``face`` falls on a cut-out texel (alpha below the material's cutoff)."""
    m = sd.face_material[face]
    if sd.alpha_mode[m] == ALPHA_OPAQUE:
        return False
    return hit_alpha(sd, face, u, v, footprint_log2) < cutoff_of(sd, m)


@wp.func
def hit_footprint_log2(t: float, spread_angle: float, normal: wp.vec3, d: wp.vec3) -> float:
    """``log2(W / |n . d|)`` of a cone of spread ``spread_angle`` hitting at distance ``t``."""
    return cone_footprint_log2(cone_width(t, spread_angle), normal, d)


@wp.func
def trace_surface(mesh: wp.uint64, sd: SurfaceData, o: wp.vec3, d: wp.vec3, max_t: float, spread_angle: float,
                  cull_back: int) -> SurfaceHit:
    """The closest hit along the unit ray (o, d) within ``max_t`` that is not a cut-out nor, with ``cull_back``,
    the back face of a single-sided material: each skipped hit restarts the query ``sd.ray_eps`` past it, at most
    ``MAX_LAYERS`` times (then a miss). The cut-out test's LOD is a cone from the ray's origin."""
    return trace_surface_cone(mesh, sd, o, d, max_t, 0.0, spread_angle, cull_back)


@wp.func
def trace_surface_cone(mesh: wp.uint64, sd: SurfaceData, o: wp.vec3, d: wp.vec3, max_t: float, width0: float,
                       spread_angle: float, cull_back: int) -> SurfaceHit:
    """:func:`trace_surface` for a cone of width ``width0`` at the origin (a path's ray after a bounce): a hit at
    distance ``t`` is tested at the footprint ``width0 + cone_width(t, spread_angle)``."""
    h = SurfaceHit()
    h.result = False
    h.t = max_t
    h.face = -1
    t0 = float(0.0)
    k = int(0)
    while k < MAX_LAYERS:  # a while loop: Warp unrolls constant ranges, 16 copies of the texture lookups
        k += 1
        q = wp.mesh_query_ray(mesh, o + d * t0, d, max_t - t0)
        if not q.result:
            return h
        t = t0 + q.t
        m = sd.face_material[q.face]
        skip = False
        if cull_back != 0 and sd.double_sided[m] == 0 and wp.dot(q.normal, d) > 0.0:
            skip = True
        if not skip and sd.has_cutouts != 0:
            skip = is_cut_out(sd, q.face, q.u, q.v,
                              cone_footprint_log2(width0 + cone_width(t, spread_angle), q.normal, d))
        if not skip:
            h.result = True
            h.t = t
            h.face = q.face
            h.u = q.u
            h.v = q.v
            h.normal = q.normal
            return h
        t0 = t + sd.ray_eps
        if t0 >= max_t:
            return h
    return h


@wp.func
def surface_visible(mesh: wp.uint64, sd: SurfaceData, p: wp.vec3, n: wp.vec3, eps: float, to: wp.vec3,
                    dist: float) -> float:
    """1 when nothing opaque blocks the segment from p (offset along n) to p + to * dist, else 0: the any-hit
    query when the scene has no cut-outs; else closest-hit queries that step through cut-out texels (at level 0),
    a surface that is not cut out blocking, and more than ``MAX_LAYERS`` cut-outs counting as blocked."""
    if dist <= 2.0 * eps:
        return 1.0
    if segment_clear(mesh, sd, p + n * eps, to, dist - 2.0 * eps):
        return 1.0
    return 0.0


@wp.func
def segment_clear(mesh: wp.uint64, sd: SurfaceData, o: wp.vec3, to: wp.vec3, tmax: float) -> bool:
    """Whether the unit ray (o, to) meets nothing opaque within (0, tmax) (:func:`surface_visible` without the
    offsets: cut-out texels let it through)."""
    if not (tmax > 0.0):
        return True
    if sd.has_cutouts == 0:
        return not wp.mesh_query_ray_anyhit(mesh, o, to, tmax)
    t0 = float(0.0)
    k = int(0)
    while k < MAX_LAYERS:  # not unrolled (as in trace_surface)
        k += 1
        q = wp.mesh_query_ray(mesh, o + to * t0, to, tmax - t0)
        if not q.result:
            return True
        if not is_cut_out(sd, q.face, q.u, q.v, -128.0):
            return False
        t0 = t0 + q.t + sd.ray_eps
        if t0 >= tmax:
            return True
    return False


@wp.func
def tangent_frame(sd: SurfaceData, face: int, i0: int, i1: int, i2: int, p0: wp.vec3, p1: wp.vec3, p2: wp.vec3,
                  tex: int, u: float, v: float, n: wp.vec3):
    """(tangent, bitangent, ok) around the unit normal ``n`` for the normal map ``tex``: the interpolated vertex
    tangents with their handedness, else ``dP/du`` of the face and the sign of its UV triangle; T orthogonalized
    against n, B = w cross(n, T). ``ok`` is False where no frame exists (degenerate UVs or tangents)."""
    tg = wp.vec3(0.0, 0.0, 0.0)
    w = float(1.0)
    if sd.has_tangents != 0:
        a = sd.tangents[i0]
        b = sd.tangents[i1]
        c = sd.tangents[i2]
        tg = wp.vec3(a[0], a[1], a[2]) * u + wp.vec3(b[0], b[1], b[2]) * v + wp.vec3(c[0], c[1], c[2]) * (
            1.0 - u - v)
        if a[3] < 0.0:
            w = -1.0
    else:
        t0, t1, t2 = slot_uvs(sd, tex, i0, i1, i2)
        du1 = t1 - t0
        du2 = t2 - t0
        det = du1[0] * du2[1] - du1[1] * du2[0]
        if wp.abs(det) > UV_DET_MIN and wp.isfinite(det):
            e1 = p1 - p0
            e2 = p2 - p0
            dpdu = (e1 * du2[1] - e2 * du1[1]) / det
            dpdv = (e2 * du1[0] - e1 * du2[0]) / det
            tg = dpdu
            # glTF's bitangent points to the image's top, -dP/dv
            if wp.dot(wp.cross(n, dpdu), -dpdv) < 0.0:
                w = -1.0
    tg = _finite3(tg - n * wp.dot(n, tg))
    lt = wp.length(tg)
    if not (lt > 1.0e-12):
        return wp.vec3(0.0, 0.0, 0.0), wp.vec3(0.0, 0.0, 0.0), False
    tg = tg / lt
    return tg, wp.cross(n, tg) * w, True


@wp.func
def eval_surface(sd: SurfaceData, face: int, u: float, v: float, d: wp.vec3, t: float, geom_n: wp.vec3,
                 spread_angle: float) -> SurfacePoint:
    """The :class:`SurfacePoint` of the hit at distance ``t`` along the unit ray ``d`` on ``face`` at barycentrics
    (u, v), ``geom_n`` its unit geometric normal (either side), its LOD that of a cone of ``spread_angle`` from the
    ray's origin. Every output is finite; factors in [0, 1]."""
    fp = float(0.0)
    if sd.lod_mode != LOD_NONE:
        fp = hit_footprint_log2(t, spread_angle, geom_n, d)
    return eval_surface_at(sd, face, u, v, d, geom_n, fp)


@wp.func
def emission_of(sd: SurfaceData, m: int, i0: int, i1: int, i2: int, p0: wp.vec3, p1: wp.vec3, p2: wp.vec3,
                u: float, v: float, footprint_log2: float) -> wp.vec3:
    """Material ``m``'s emitted radiance at barycentrics (u, v) of a face: ``emission`` x emissive texture RGB,
    finite and >= 0."""
    em = sample_slot(sd, m, SLOT_EMISSIVE, i0, i1, i2, p0, p1, p2, u, v, footprint_log2)
    return _finite3(wp.max(wp.cw_mul(sd.emission[m], wp.vec3(em[0], em[1], em[2])), wp.vec3(0.0, 0.0, 0.0)))


@wp.func
def surface_emission(sd: SurfaceData, face: int, u: float, v: float, footprint_log2: float) -> wp.vec3:
    """The emitted radiance at barycentrics (u, v) of ``face`` (:func:`emission_of` of its material), with the
    texture footprint ``log2(W / |n . d|)`` (-128: the finest level)."""
    m = sd.face_material[face]
    i0 = load1_i32(sd.indices, face * 3 + 0)
    i1 = load1_i32(sd.indices, face * 3 + 1)
    i2 = load1_i32(sd.indices, face * 3 + 2)
    return emission_of(sd, m, i0, i1, i2, load1_vec3(sd.points, i0), load1_vec3(sd.points, i1),
                       load1_vec3(sd.points, i2), u, v, footprint_log2)


@wp.func
def eval_surface_at(sd: SurfaceData, face: int, u: float, v: float, d: wp.vec3, geom_n: wp.vec3,
                    footprint_log2: float) -> SurfacePoint:
    """:func:`eval_surface` with the texture footprint ``log2(W / |n . d|)`` given (ignored with ``LOD_NONE``)."""
    m = sd.face_material[face]
    i0 = load1_i32(sd.indices, face * 3 + 0)
    i1 = load1_i32(sd.indices, face * 3 + 1)
    i2 = load1_i32(sd.indices, face * 3 + 2)
    p0 = load1_vec3(sd.points, i0)
    p1 = load1_vec3(sd.points, i1)
    p2 = load1_vec3(sd.points, i2)
    fp = footprint_log2
    sp = SurfacePoint()
    bc = sd.base_color[m]
    c = sample_slot(sd, m, SLOT_BASE_COLOR, i0, i1, i2, p0, p1, p2, u, v, fp)
    sp.base_color = wp.vec3(_unit(bc[0] * c[0]), _unit(bc[1] * c[1]), _unit(bc[2] * c[2]))
    sp.alpha = _unit(bc[3] * c[3])
    mr = sample_slot(sd, m, SLOT_METALLIC_ROUGHNESS, i0, i1, i2, p0, p1, p2, u, v, fp)
    sp.roughness = _unit(sd.roughness[m] * mr[1])
    sp.metallic = _unit(sd.metallic[m] * mr[2])
    oc = sample_slot(sd, m, SLOT_OCCLUSION, i0, i1, i2, p0, p1, p2, u, v, fp)
    sp.occlusion = _unit(1.0 + sd.occlusion_strength[m] * (oc[0] - 1.0))
    sp.emission = emission_of(sd, m, i0, i1, i2, p0, p1, p2, u, v, fp)
    sp.specular = _unit(sd.specular[m])
    sp.transmission = _unit(sd.transmission[m])
    sp.ior = wp.clamp(sd.ior[m], 1.0, 5.0)
    # the normal on the front side of the face (the side its winding faces, where the tangent frame is defined),
    # mapped there and turned to the viewer at the end (glTF flips a double-sided back face's normal)
    fn = geom_n
    n = fn
    if load1_u8(sd.smooth, face) != wp.uint8(0):
        s = sd.vnormals[i0] * u + sd.vnormals[i1] * v + sd.vnormals[i2] * (1.0 - u - v)
        ls = wp.length(s)
        if ls > 1.0e-12 and wp.isfinite(ls):
            s = s / ls
            if wp.dot(s, fn) > 0.0:
                n = s
    tex = sd.texture[m, SLOT_NORMAL]
    if tex >= 0:
        nt = sample_slot(sd, m, SLOT_NORMAL, i0, i1, i2, p0, p1, p2, u, v, fp)
        tg, bt, ok = tangent_frame(sd, face, i0, i1, i2, p0, p1, p2, tex, u, v, n)
        if ok:
            k = sd.normal_scale[m]
            x = (2.0 * nt[0] - 1.0) * k
            y = (2.0 * nt[1] - 1.0) * k
            z = 2.0 * nt[2] - 1.0
            nm = _finite3(tg * x + bt * y + n * z)
            ln = wp.length(nm)
            if ln > 1.0e-12 and wp.isfinite(ln):
                nm = nm / ln
                if wp.dot(nm, fn) > 0.0:
                    n = nm
    if wp.dot(fn, d) > 0.0:
        n = -n  # a back face
    sp.normal = n
    return sp
