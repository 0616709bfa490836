"""Primary rays traced in packets of 8 on the CPU: one walk of the scene BVH for 8 neighbouring pixels.

``wp.mesh_query_ray`` walks the BVH once per ray, one ray at a time. Primary rays of neighbouring pixels enter
nearly the same nodes, so here up to 8 rays share one walk: each inner node's two boxes are loaded once and
tested against the 8 rays in one loop (which the compiler turns into SIMD), and a node is entered while any ray
of the packet reaches it (a mask of those rays goes with it). A leaf tests its triangles against the rays of the
mask only: when the packet's rays share their axes (Warp's watertight test orders the axes by the direction's
largest component, which neighbouring primary rays share), the test runs for all 8 rays in one loop as a filter,
and the rays it passes (a hit nearer than the ray's nearest so far, or a case for the exact fallback) are tested
again one at a time, which decides.

Every ray gets what ``wp.mesh_query_ray`` gives it, because it sees the same tests in the same order:

* the box test is Warp's ``intersect_ray_aabb`` on the same operands in the same order, and a child is entered by
  a ray when its box is hit at a distance below the ray's nearest hit so far, as in Warp's walk (its min and max
  differ from Warp's only where an operand is NaN, which cannot happen for the rays the packets take: a finite
  eye, finite nonzero direction components with finite reciprocals);
* each ray visits the two children of a node in its own order, the one ``mesh_query_ray`` takes (the nearer
  entry first, the right child on equal entries): where the rays entering both children disagree, the walk splits,
  those preferring the right child walking it and then the left one on their own. The order matters: a triangle
  can be hit an ulp below its box's entry distance, so which of two such hits is kept depends on it (a review
  found rays on coplanar box faces where a shared order kept the other face);
* the triangle test is the operations of Warp's ``intersect_ray_tri_woop`` in its order (its per-ray part, the
  axes and the shear, computed once per ray), and a hit is kept when 0 <= t < the nearest so far;
* the normal is the kept triangle's, normalized by Warp's ``normalize``.

So t, face, u, v and the normal are the same bits, ties included. Any other ray (a zero direction component,
where Warp uses its robust box test; an infinite component, or one so small that its reciprocal overflows; a
non-finite eye) is traced by ``mesh_query_ray`` itself, as is a ray whose split walk would overflow the packet's
stack (Warp's trees are at most 31 levels deep, so this is not seen). Compiled for CUDA, every ray is traced by
``mesh_query_ray`` (the packet path is for the CPU: the G-buffer's CUDA kernels do not call it).

Results are written per ray: the distance (``max_t`` on a miss), the face (-1 on a miss), (u, v) and the unit
normal (left as they were on a miss).
"""

import warp as wp

PACKET = 8  # rays per packet

# {dir}, {t}, {face}, {uv}, {nrm}: the address of ray l's direction and outputs (set per signature below)
_BODY = """
    const int n = count < 8 ? count : 8;
    wp::Mesh mesh = wp::mesh_get(mesh_id);
    wp::vec3 d[8];
    float best[8];
    int face[8];
    float bu[8], bv[8];
    wp::vec3 bn[8];
    unsigned active = 0u;
    for (int l = 0; l < 8; ++l) {{
        best[l] = max_t;  // lanes past n too (never in a mask, but read by the 8-wide loops)
        face[l] = -1;
    }}
    // ray l traced by mesh_query_ray itself (the rays the packet does not take, and those it drops)
    auto single = [&](int l) {{
        float qt, qu, qv, qs;
        wp::vec3 qn;
        int qf;
        best[l] = max_t;
        face[l] = -1;
        if (wp::mesh_query_ray(mesh_id, eye, d[l], max_t, qt, qu, qv, qs, qn, qf)) {{
            best[l] = qt; face[l] = qf; bu[l] = qu; bv[l] = qv; bn[l] = qn;
        }}
    }};
    const bool eye_ok = __builtin_isfinite(eye[0]) && __builtin_isfinite(eye[1]) && __builtin_isfinite(eye[2]);
    for (int l = 0; l < n; ++l) {{
        d[l] = *(const wp::vec3*)({dir});
#if !defined(__CUDACC__)
        // the packet's box test is exact for a finite eye and finite reciprocals of nonzero direction components
        // (no NaN in the slab distances, so its min and max agree with Warp's); other rays go to mesh_query_ray
        if (eye_ok && d[l][0] != 0.0f && d[l][1] != 0.0f && d[l][2] != 0.0f && __builtin_isfinite(d[l][0])
            && __builtin_isfinite(d[l][1]) && __builtin_isfinite(d[l][2]) && __builtin_isfinite(1.0f / d[l][0])
            && __builtin_isfinite(1.0f / d[l][1]) && __builtin_isfinite(1.0f / d[l][2]))
            active |= 1u << l;
        else
#endif
            single(l);
    }}
#if !defined(__CUDACC__)
    if (active) {{
        float rx[8], ry[8], rz[8];
        for (int l = 0; l < 8; ++l) {{
            // lanes past n: a copy of lane 0 (never in a mask)
            const wp::vec3 dl = d[l < n ? l : 0];
            rx[l] = 1.0f / dl[0];
            ry[l] = 1.0f / dl[1];
            rz[l] = 1.0f / dl[2];
        }}
        // the per-ray part of intersect_ray_tri_woop (its axes and shear), once per ray instead of per triangle
        int kx[8], ky[8], kz[8];
        float sx[8], sy[8], sz[8];
        for (int l = 0; l < 8; ++l) {{
            const wp::vec3 dl = d[l < n ? l : 0];
            int z = wp::max_dim(dl);
            int a = z + 1;
            if (a == 3) a = 0;
            int b = a + 1;
            if (b == 3) b = 0;
            if (dl[z] < 0.0f) {{
                const int tmp = a;
                a = b;
                b = tmp;
            }}
            kx[l] = a; ky[l] = b; kz[l] = z;
            sx[l] = dl[a] / dl[z];
            sy[l] = dl[b] / dl[z];
            sz[l] = 1.0f / dl[z];
        }}
        // all rays of the packet with the same axes (the usual case for neighbouring primary rays)
        bool uniform = true;
        for (int l = 1; l < 8; ++l)
            uniform = uniform && kx[l] == kx[0] && ky[l] == ky[0] && kz[l] == kz[0];
        const int ux = kx[0], uy = ky[0], uz = kz[0];
        // a walk that splits pushes up to 3 entries a level; a ray whose walk would overflow the stack is dropped
        // from the packet and traced by mesh_query_ray (Warp's trees are at most 31 deep: not seen)
        unsigned long long stack[96];
        unsigned smask[96];
        unsigned dropped = 0u;
        int sp = 0;
        unsigned long long cur = wp::bvh_query_node_load(mesh.bvh, *mesh.bvh.root);
        unsigned cmask = active;
        for (;;) {{
            if (wp::bvh_query_node_is_leaf(cur)) {{
                const int pb = wp::bvh_query_node_lower_payload(cur);
                const int pe = wp::bvh_query_node_upper_payload(cur);
                for (int pc = pb; pc < pe; ++pc) {{
                    const int prim = mesh.bvh.primitive_indices[pc];
                    const wp::vec3 p = mesh.points[mesh.indices[prim * 3 + 0]];
                    const wp::vec3 q = mesh.points[mesh.indices[prim * 3 + 1]];
                    const wp::vec3 r = mesh.points[mesh.indices[prim * 3 + 2]];
                    const wp::vec3 A = p - eye;
                    const wp::vec3 B = q - eye;
                    const wp::vec3 C = r - eye;
                    unsigned todo = cmask;
                    if (uniform && (cmask & (cmask - 1u))) {{
                        // the rays share their axes: the test's operations for all 8 rays in one loop (SIMD), the
                        // same operations on the same operands as the scalar test below; rays whose U, V or W is 0
                        // (the exact fallback) and rays that hit go to the scalar test
                        const float Akx = A[ux], Aky = A[uy], Akz = A[uz];
                        const float Bkx = B[ux], Bky = B[uy], Bkz = B[uz];
                        const float Ckx = C[ux], Cky = C[uy], Ckz = C[uz];
                        int go[8];
                        for (int l = 0; l < 8; ++l) {{
                            const float Sx = sx[l], Sy = sy[l];
                            const float Ax = Akx - Sx * Akz;
                            const float Ay = Aky - Sy * Akz;
                            const float Bx = Bkx - Sx * Bkz;
                            const float By = Bky - Sy * Bkz;
                            const float Cx = Ckx - Sx * Ckz;
                            const float Cy = Cky - Sy * Ckz;
                            float cd = Cy * Bx;
                            const float U = fmaf(Cx, By, -cd) + fmaf(-Cy, Bx, cd);
                            cd = Ay * Cx;
                            const float V = fmaf(Ax, Cy, -cd) + fmaf(-Ay, Cx, cd);
                            cd = By * Ax;
                            const float W = fmaf(Bx, Ay, -cd) + fmaf(-By, Ax, cd);
                            const int zero = (U == 0.0f) | (V == 0.0f) | (W == 0.0f);
                            const int outside = ((U < 0.0f) | (V < 0.0f) | (W < 0.0f)) & ((U > 0.0f) | (V > 0.0f) | (W > 0.0f));
                            const float det = U + V + W;
                            const float T = U * (sz[l] * Akz) + V * (sz[l] * Bkz) + W * (sz[l] * Ckz);
                            const float Ts = __builtin_bit_cast(float, __builtin_bit_cast(int, T)
                                ^ (__builtin_bit_cast(int, det) & (int)0x80000000));
                            const float tt = T * (1.0f / det);
                            go[l] = zero | ((outside == 0) & (det != 0.0f) & (Ts >= 0.0f) & (tt < best[l]) & (tt >= 0.0f));
                        }}
                        unsigned g = 0u;
                        for (int l = 0; l < 8; ++l) g |= (unsigned)go[l] << l;
                        todo &= g;
                    }}
                    for (unsigned m = todo; m; m &= m - 1u) {{
                        const int l = __builtin_ctz(m);
                        // intersect_ray_tri_woop's operations, in its order, with the ray's part above
                        const float Sx = sx[l], Sy = sy[l];
                        const int ix = kx[l], iy = ky[l], iz = kz[l];
                        const float Ax = A[ix] - Sx * A[iz];
                        const float Ay = A[iy] - Sy * A[iz];
                        const float Bx = B[ix] - Sx * B[iz];
                        const float By = B[iy] - Sy * B[iz];
                        const float Cx = C[ix] - Sx * C[iz];
                        const float Cy = C[iy] - Sy * C[iz];
                        float U = wp::diff_product(Cx, By, Cy, Bx);
                        float V = wp::diff_product(Ax, Cy, Ay, Cx);
                        float W = wp::diff_product(Bx, Ay, By, Ax);
                        if (U == 0.0f || V == 0.0f || W == 0.0f) {{
                            U = (float)((double)Cx * (double)By - (double)Cy * (double)Bx);
                            V = (float)((double)Ax * (double)Cy - (double)Ay * (double)Cx);
                            W = (float)((double)Bx * (double)Ay - (double)By * (double)Ax);
                        }}
                        if ((U < 0.0f || V < 0.0f || W < 0.0f) && (U > 0.0f || V > 0.0f || W > 0.0f)) continue;
                        const float det = U + V + W;
                        if (det == 0.0f) continue;
                        const float Az = sz[l] * A[iz];
                        const float Bz = sz[l] * B[iz];
                        const float Cz = sz[l] * C[iz];
                        const float T = U * Az + V * Bz + W * Cz;
                        if (wp::xorf(T, wp::sign_mask(det)) < 0.0f) continue;
                        const float rcp = 1.0f / det;
                        const float tt = T * rcp;
                        if (tt < best[l] && tt >= 0.0f) {{
                            best[l] = tt; face[l] = prim; bu[l] = U * rcp; bv[l] = V * rcp;
                            bn[l] = wp::cross(q - p, r - p);
                        }}
                    }}
                }}
                if (sp == 0) break;
                --sp;
                cur = stack[sp];
                cmask = smask[sp] & ~dropped;
                continue;
            }}
            const int li = wp::bvh_query_node_lower_payload(cur);
            const int ri = wp::bvh_query_node_upper_payload(cur);
            const wp::BVHPackedNodeHalf ll = wp::bvh_load_node(mesh.bvh.node_lowers, li);
            const wp::BVHPackedNodeHalf lu = wp::bvh_load_node(mesh.bvh.node_uppers, li);
            const wp::BVHPackedNodeHalf rl = wp::bvh_load_node(mesh.bvh.node_lowers, ri);
            const wp::BVHPackedNodeHalf ru = wp::bvh_load_node(mesh.bvh.node_uppers, ri);
            // the slab distances of intersect_ray_aabb: (bound - origin) * (1 / dir), per axis
            const float a0x = ll.x - eye[0], a0y = ll.y - eye[1], a0z = ll.z - eye[2];
            const float b0x = lu.x - eye[0], b0y = lu.y - eye[1], b0z = lu.z - eye[2];
            const float a1x = rl.x - eye[0], a1y = rl.y - eye[1], a1z = rl.z - eye[2];
            const float b1x = ru.x - eye[0], b1y = ru.y - eye[1], b1z = ru.z - eye[2];
            float t0[8], t1[8];
            int h0[8], h1[8];
            // intersect_ray_aabb for ray l and one child (lower - eye = a, upper - eye = b): entry distance, hit
#define FW_SLAB(ax, ay, az, bx, by, bz, T, H) {{ \
                float l1 = ax * rx[l], l2 = bx * rx[l]; \
                float lmin = l1 < l2 ? l1 : l2, lmax = l1 > l2 ? l1 : l2; \
                l1 = ay * ry[l]; l2 = by * ry[l]; \
                float mn = l1 < l2 ? l1 : l2, mx = l1 > l2 ? l1 : l2; \
                lmin = mn > lmin ? mn : lmin; lmax = mx < lmax ? mx : lmax; \
                l1 = az * rz[l]; l2 = bz * rz[l]; \
                mn = l1 < l2 ? l1 : l2; mx = l1 > l2 ? l1 : l2; \
                lmin = mn > lmin ? mn : lmin; lmax = mx < lmax ? mx : lmax; \
                T[l] = lmin; \
                H[l] = (lmax >= 0.0f) & (lmax >= lmin) & (lmin < best[l]); }}
            for (int l = 0; l < 8; ++l) {{
                FW_SLAB(a0x, a0y, a0z, b0x, b0y, b0z, t0, h0)
                FW_SLAB(a1x, a1y, a1z, b1x, b1y, b1z, t1, h1)
            }}
#undef FW_SLAB
            unsigned m0 = 0u, m1 = 0u;
            for (int l = 0; l < 8; ++l) {{
                m0 |= (unsigned)h0[l] << l;
                m1 |= (unsigned)h1[l] << l;
            }}
            m0 &= cmask;
            m1 &= cmask;
            const unsigned long long ln = wp::bvh_query_node_pack(ll, lu);
            const unsigned long long rn = wp::bvh_query_node_pack(rl, ru);
            bool pop = false;
            if (m0 && m1) {{
                // each ray visits the two children in its own order, as mesh_query_ray does (the nearer entry
                // first; the right one on equal entries): the order decides which of two hits an ulp apart is
                // kept, since a triangle can be hit just below its box's entry distance
                const unsigned both = m0 & m1;
                unsigned pl = 0u;
                for (int l = 0; l < 8; ++l) pl |= (unsigned)(t0[l] < t1[l]) << l;
                const unsigned pref_l = both & pl, pref_r = both & ~pl;
                if (pref_l && pref_r) {{
                    // the rays that enter both disagree: those preferring the right child walk it and then the
                    // left one on their own; the others (with the rays entering one child) go left first
                    if (sp + 3 > 96) {{
                        dropped |= cmask;
                        pop = true;
                    }} else {{
                        const unsigned a1 = m1 & ~pref_r;
                        stack[sp] = ln; smask[sp] = pref_r; ++sp;
                        stack[sp] = rn; smask[sp] = pref_r; ++sp;
                        if (a1) {{ stack[sp] = rn; smask[sp] = a1; ++sp; }}
                        cur = ln;
                        cmask = m0 & ~pref_r;
                    }}
                }} else if (sp + 1 > 96) {{
                    dropped |= cmask;
                    pop = true;
                }} else {{
                    const bool left_first = pref_l != 0u || both == 0u;
                    stack[sp] = left_first ? rn : ln;
                    smask[sp] = left_first ? m1 : m0;
                    ++sp;
                    cur = left_first ? ln : rn;
                    cmask = left_first ? m0 : m1;
                }}
            }} else if (m0) {{
                cur = ln;
                cmask = m0;
            }} else if (m1) {{
                cur = rn;
                cmask = m1;
            }} else {{
                pop = true;
            }}
            if (pop) {{
                if (sp == 0) break;
                --sp;
                cur = stack[sp];
                cmask = smask[sp] & ~dropped;
            }}
        }}
        for (unsigned m = active & ~dropped; m; m &= m - 1u) {{
            const int l = __builtin_ctz(m);
            if (face[l] >= 0) bn[l] = wp::normalize(bn[l]);
        }}
        for (unsigned m = dropped; m; m &= m - 1u) {{
            single(__builtin_ctz(m));
        }}
    }}
#endif
    for (int l = 0; l < n; ++l) {{
        *(float*)({t}) = best[l];
        *(int*)({face}) = face[l];
        if (face[l] >= 0) {{
            *(wp::vec2*)({uv}) = wp::vec2(bu[l], bv[l]);
            *(wp::vec3*)({nrm}) = bn[l];
        }}
    }}
"""

_A1 = "(char*){a}.data + (size_t)(start + l) * {a}.strides[0]"
_A2 = "(char*){a}.data + (size_t)y * {a}.strides[0] + (size_t)(x0 + l) * {a}.strides[1]"


def _body(addr: str) -> str:
    return _BODY.format(dir=addr.format(a="dirs"), t=addr.format(a="out_t"), face=addr.format(a="out_face"),
                        uv=addr.format(a="out_uv"), nrm=addr.format(a="out_n"))


@wp.func_native(_body(_A1))
def trace_packet(mesh_id: wp.uint64, eye: wp.vec3, max_t: float, dirs: wp.array(dtype=wp.vec3), start: int,
                 count: int, out_t: wp.array(dtype=float), out_face: wp.array(dtype=wp.int32),
                 out_uv: wp.array(dtype=wp.vec2), out_n: wp.array(dtype=wp.vec3)):
    """Rays ``start`` .. ``start + min(count, 8) - 1`` of ``dirs`` from ``eye`` (1-D arrays, unchecked)."""
    ...


@wp.func_native(_body(_A2))
def trace_packet_row(mesh_id: wp.uint64, eye: wp.vec3, max_t: float, dirs: wp.array2d(dtype=wp.vec3), y: int,
                     x0: int, count: int, out_t: wp.array2d(dtype=float), out_face: wp.array2d(dtype=wp.int32),
                     out_uv: wp.array2d(dtype=wp.vec2), out_n: wp.array2d(dtype=wp.vec3)):
    """Rays [y, x0] .. [y, x0 + min(count, 8) - 1] of ``dirs`` from ``eye`` (2-D arrays, unchecked)."""
    ...


@wp.kernel(enable_backward=False)
def packet_ray_kernel(mesh: wp.uint64, eye: wp.vec3, dirs: wp.array(dtype=wp.vec3), max_t: float,
                      out_t: wp.array(dtype=float), out_face: wp.array(dtype=wp.int32),
                      out_uv: wp.array(dtype=wp.vec2), out_n: wp.array(dtype=wp.vec3), row0: int):
    """Thread i traces rays 8 i .. 8 i + 7 of ``dirs`` in one packet (``row0``: the band offset of
    ``foveawarp.parallel``)."""
    i = wp.tid() + row0
    trace_packet(mesh, eye, max_t, dirs, i * PACKET, dirs.shape[0] - i * PACKET, out_t, out_face, out_uv, out_n)


@wp.kernel(enable_backward=False)
def single_ray_kernel(mesh: wp.uint64, eye: wp.vec3, dirs: wp.array(dtype=wp.vec3), max_t: float,
                      out_t: wp.array(dtype=float), out_face: wp.array(dtype=wp.int32),
                      out_uv: wp.array(dtype=wp.vec2), out_n: wp.array(dtype=wp.vec3), row0: int):
    """``wp.mesh_query_ray`` per ray, with the outputs of :func:`trace_packet` (the tests' and the benchmark's
    comparison)."""
    i = wp.tid() + row0
    q = wp.mesh_query_ray(mesh, eye, dirs[i], max_t)
    if q.result:
        out_t[i] = q.t
        out_face[i] = q.face
        out_uv[i] = wp.vec2(q.u, q.v)
        out_n[i] = q.normal
    else:
        out_t[i] = max_t
        out_face[i] = -1
