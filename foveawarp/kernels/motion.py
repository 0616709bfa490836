"""Rigid object motion on the device: an animated object's vertices (and vertex normals) moved from their rest
positions by its 4x4 transform, in float64 as ``Scene.vertices_at`` / ``Scene.normals_at`` compute them on the
host, so a frame of an animated scene uploads one matrix per moving object instead of every vertex."""

import warp as wp


@wp.func
def _affine64(m: wp.mat44d, v: wp.vec3, translate: int) -> wp.vec3:
    """(m[:3, :3] @ v + translate * m[:3, 3]) in float64, rounded to float32 per component (the host's
    ``(v.astype(float64) @ m[:3, :3].T + m[:3, 3]).astype(float32)``)."""
    x = wp.float64(v[0])
    y = wp.float64(v[1])
    z = wp.float64(v[2])
    r0 = m[0, 0] * x + m[0, 1] * y + m[0, 2] * z
    r1 = m[1, 0] * x + m[1, 1] * y + m[1, 2] * z
    r2 = m[2, 0] * x + m[2, 1] * y + m[2, 2] * z
    if translate != 0:
        r0 = r0 + m[0, 3]
        r1 = r1 + m[1, 3]
        r2 = r2 + m[2, 3]
    return wp.vec3(wp.float32(r0), wp.float32(r1), wp.float32(r2))


@wp.kernel(enable_backward=False)
def rigid_motion_kernel(
    mats: wp.array(dtype=wp.mat44d),
    k: int,
    start: int,
    rest: wp.array(dtype=wp.vec3),
    rest_normals: wp.array(dtype=wp.vec3),
    move_normals: int,
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    row0: int,
):
    """Vertex ``start + i`` of one object: position (and, with ``move_normals``, vertex normal, rotated without
    the translation and not renormalized, as on the host) = ``mats[k]``, the object's transform, applied to its rest
    value (the transforms are read from the device, so that a captured CUDA graph of the update takes each frame's
    from one copy). A thread per vertex of the object, in bands on the CPU (``foveawarp.parallel``: each thread
    writes only its own vertex)."""
    i = wp.tid() + row0 + start
    m = mats[k]
    points[i] = _affine64(m, rest[i], 1)
    if move_normals != 0:
        normals[i] = _affine64(m, rest_normals[i], 0)
