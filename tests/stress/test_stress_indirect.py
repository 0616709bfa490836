"""Stress: one-bounce indirect light (ALGORITHMS.md C) with receivers exactly at VPL positions, a hair away
from them, at the light, with zero / flipped / tangent normals, over scenes scaled 1e-4 to 1e5, spot and point
lights, light inside or outside the geometry."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

import foveawarp as fw
from foveawarp import IndirectConfig, ops
from foveawarp.scenes import SceneBuilder
from stress_util import assert_finite, batch, examples


def _room(scale, light_kind, light_inside, cone):
    """A floor, two walls and a box (all scaled) lit by one light."""
    b = SceneBuilder()
    s = scale
    b.add_quad((-s, 0, -s), (0, 0, 2 * s), (2 * s, 0, 0), (0.8, 0.7, 0.6))
    b.add_quad((-s, 0, -s), (2 * s, 0, 0), (0, 2 * s, 0), (0.2, 0.9, 0.3))
    b.add_quad((-s, 0, -s), (0, 2 * s, 0), (0, 0, 2 * s), (0.9, 0.1, 0.1))
    b.add_box((0.3 * s, 0.25 * s, 0.2 * s), (0.5 * s, 0.5 * s, 0.5 * s), (1.0, 1.0, 1.0))
    pos = (0.0, 1.5 * s, 0.3 * s) if light_inside else (0.0, 0.25 * s, 0.2 * s)  # inside the box: all blocked
    light = fw.Light(kind=light_kind, position=pos, direction=(0.1, -1.0, -0.2), cone_deg=cone,
                     intensity=(3.0, 2.0, 1.0), penumbra=0.3)
    return b.build(lights=[light])


@examples(60, 400)
@given(scale=st.sampled_from([1e-4, 1e-2, 1.0, 1e2, 1e5]), light_kind=st.sampled_from(["spot", "point"]),
       light_inside=st.booleans(), cone=st.sampled_from([0.5, 45.0, 90.0, 180.0]),
       rsm=st.sampled_from([8, 16, 32]), d_min_rel=st.sampled_from([1e-6, 0.02, 1.0]),
       seed=st.integers(0, 2**32 - 1))
def test_vpls_at_the_receiver(device, cases, scale, light_kind, light_inside, cone, rsm, d_min_rel, seed):
    """Receivers placed exactly at VPL positions (normal = the VPL's, flipped, tangent, zero), offset from a
    VPL by 1e-30, one ulp, d_min / 2 or d_min, at the light itself, and at random places: the exact all-VPL
    sum, the light cut, the per-receiver traversal and the sampled RSM are finite, >= 0, and below the
    bound albedo / pi^2 * sum(flux) / d_min^2 (each VPL term is at most flux / d_min^2); the light cut and
    the traversal agree."""
    light_inside = light_inside and light_kind == "spot"
    scene = _room(scale, light_kind, light_inside, cone)
    lvl = int(round(math.log2(rsm)))
    cfg = IndirectConfig(rsm_size=rsm, start_level=min(1, lvl), limit_level=min(2, lvl), d_min_rel=d_min_rel,
                         refine_threshold=1e-6, refine_budget=32, refine_min_ratio=0.0)
    ds = fw.DeviceScene(scene, device)
    r = ops.reflective_shadow_map(ds, config=cfg)
    flux = assert_finite("rsm flux", r["flux"]).reshape(-1, 3)
    vpos = assert_finite("rsm position", r["position"]).reshape(-1, 3)
    vnrm = assert_finite("rsm normal", r["normal"]).reshape(-1, 3)
    assert (flux >= 0).all()
    rng = np.random.default_rng(seed)
    n = batch(device, 64)
    lit = np.flatnonzero(flux.sum(axis=1) > 0)
    pick = rng.choice(lit if lit.size else np.arange(flux.shape[0]), size=n)
    p = vpos[pick].astype(np.float64)
    nv = vnrm[pick].astype(np.float64)
    kind = np.arange(n) % 8
    tang = np.cross(nv, rng.normal(size=(n, 3)))
    tang /= np.maximum(np.linalg.norm(tang, axis=1, keepdims=True), 1e-30)
    d_min = d_min_rel * scene.extent
    normals = np.where((kind == 0)[:, None], nv, 0.0)
    normals = np.where((kind == 1)[:, None], -nv, normals)
    normals = np.where((kind == 2)[:, None], tang, normals)  # kind 3: zero normal
    off = rng.normal(size=(n, 3))
    off /= np.linalg.norm(off, axis=1, keepdims=True)
    p = np.where((kind == 4)[:, None], p + off * 1e-30 * scale, p)
    p = np.where((kind == 5)[:, None], np.nextafter(p.astype(np.float32), np.float32(np.inf)), p)
    p = np.where((kind == 6)[:, None], p + off * rng.choice([0.5, 1.0]) * d_min, p)
    p = np.where((kind == 7)[:, None], np.asarray(scene.lights[0].position), p)
    rnd = rng.normal(size=(n, 3))
    normals = np.where((kind >= 4)[:, None], rnd / np.linalg.norm(rnd, axis=1, keepdims=True), normals)
    p = p.astype(np.float32)
    normals = normals.astype(np.float32)
    alb = rng.random((n, 3)).astype(np.float32)
    bound = alb.astype(np.float64) / math.pi ** 2 * flux.astype(np.float64).sum(axis=0) / max(d_min * d_min,
                                                                                               1e-30)
    plain = dataclasses.replace(cfg, refine_budget=0)  # extended emitters, no per-receiver refinement
    outs = {
        "exact": ops.indirect_vpl_exact(ds, p, normals, alb, config=cfg),
        "cut": ops.indirect_light_tree(ds, p, normals, alb, config=plain),
        "traverse": ops.indirect_light_tree(ds, p, normals, alb, config=plain, traversal="per-receiver"),
        "cut refined": ops.indirect_light_tree(ds, p, normals, alb, config=cfg),
        "traverse refined": ops.indirect_light_tree(ds, p, normals, alb, config=cfg, traversal="per-receiver"),
        "sampled": ops.indirect_rsm_sampled(ds, p, normals, alb, config=cfg, samples=min(64, rsm * rsm)),
    }
    for name, o in outs.items():
        assert_finite(f"indirect {name} scale={scale}", o)
        assert o.min() >= 0.0, name
        lim = bound * (rsm * rsm / min(64, rsm * rsm) if name == "sampled" else 1.0)
        assert (o <= lim * (1 + 1e-4) + 1e-30).all(), f"{name}: above the d_min bound"
        assert (o[kind == 3] == 0).all(), f"{name}: a zero normal received light"
    np.testing.assert_allclose(outs["cut"], outs["traverse"], rtol=1e-4,
                               atol=float(1e-5 * max(outs["cut"].max(), 1e-30)))
    cases.add("indirect receivers at / near VPLs (6 methods each)", n)
