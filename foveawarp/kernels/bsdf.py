"""The glTF 2.0 metallic-roughness BSDF: evaluation, sampling and pdf in the local shading frame.

The model is glTF 2.0's, Appendix B ("BRDF Implementation"), written as its normative mix of a dielectric and a
metal BRDF sharing one GGX specular lobe::

    specular_brdf   = D(h) * V(wo, wi)                         (V = G2 / (4 |n.wo| |n.wi|))
    dielectric_brdf = mix(base_color / pi, specular_brdf, Fd)  Fd = s * (0.04 + 0.96 * (1 - |wo.h|)^5)
    metal_brdf      = specular_brdf * Fm                       Fm = base_color + (1 - base_color) * (1 - |wo.h|)^5
    f               = mix(dielectric_brdf, metal_brdf, metallic)

so that, expanded,

    f = (1 - metallic) * (1 - Fd) * base_color / pi  +  F * D * V,     F = (1 - metallic) * Fd + metallic * Fm

``F`` is Schlick's Fresnel with ``F0 = lerp(0.04 s, base_color, metallic)`` and ``F90 = lerp(s, 1, metallic)``;
with ``s = 1`` this is ``F0 = lerp(0.04, base_color, metallic)``. The Lambert diffuse IS weighted by
``1 - Fd`` (the scalar dielectric Fresnel at the half vector), as the spec's mix form says; the spec's older
"simplified" pseudocode weighted it by the RGB ``1 - F`` instead, which differs for 0 < metallic < 1 and was
corrected in the spec (KhronosGroup/glTF#2386). ``s`` is ``KHR_materials_specular``'s ``specularFactor`` with
``specularColorFactor = 1`` (1 for the core material; 0 leaves a pure Lambert dielectric).

- ``D``: GGX / Trowbridge-Reitz (Walter et al. 2007, eq. 33), ``alpha = roughness^2`` (glTF's perceptual
  roughness) raised to at least :data:`ALPHA_MIN`, so that ``D <= 1 / (pi ALPHA_MIN^2)`` stays finite.
- ``G2``: height-correlated Smith masking-shadowing (Heitz 2014, "Understanding the Masking-Shadowing Function
  in Microfacet-Based BRDFs", JCGT 3(2)), ``G2 = 1 / (1 + Lambda(wo) + Lambda(wi))``, with the GGX
  ``Lambda(z) = (sqrt(z^2 + alpha^2 (1 - z^2)) / z - 1) / 2``; it is evaluated through
  ``V = 0.5 / (z_i a_o + z_o a_i)``, ``a = sqrt(z^2 + alpha^2 (1 - z^2))``, which never divides by a cosine.
- Sampling: the specular lobe by GGX visible normals (Heitz 2018, "Sampling the GGX Distribution of Visible
  Normals", JCGT 7(4)) reflected about the sampled normal, ``pdf = D(h) G1(wo) / (4 wo.z)`` (the visible-normal
  density ``G1(wo) (wo.h) D(h) / wo.z`` times the reflection Jacobian ``1 / (4 wo.h)``); the diffuse lobe by a
  cosine-weighted hemisphere,
  ``pdf = wi.z / pi``. A lobe is chosen with probability proportional to its weight at ``wo``:
  ``w_spec = lum(F(wo.z))`` and ``w_diff = (1 - metallic) (1 - Fd(wo.z)) lum(base_color)`` (``lum``: Rec. 709
  luminance); the pdf of a direction is the mixture of both lobes' pdfs, as multiple importance sampling needs.

Conventions (pbrt-v4's BxDFs): every direction is in the LOCAL shading frame, z along the shading normal,
``wo`` towards the viewer, ``wi`` towards the light, both pointing away from the surface, ``wo.z = cos theta_o``.
:func:`bsdf_eval` returns ``f`` WITHOUT the cosine ``wi.z``. Directions need not be unit length (they are
normalized here); a zero, infinite or NaN direction, or one at or below the surface (``z <= 0``), gives
``f = 0`` and ``pdf = 0``. Cosines below :data:`COS_MIN` are raised to it inside the masking term, which keeps
``f`` finite at grazing angles. :func:`make_material` clamps the material's parameters to [0, 1] (NaN to 0).

Not energy conserving at grazing angles: the ``1 - Fd(wo.h)`` weight leaves most of the diffuse lobe in place
while the specular lobe reflects nearly all light, so a white dielectric's directional albedo exceeds 1 away
from normal incidence (about 1.48 for roughness 0.2 at wo.z = 0.05 by quadrature; below 1 at normal incidence);
the metal (``metallic = 1``) and each lobe alone stay at or below 1. The spec's model has no multiple-scattering
compensation either: a white metal's albedo falls to 0.31 at roughness 1 seen head-on.
"""

import warp as wp

__all__ = [
    "ALPHA_MIN",
    "COS_MIN",
    "SurfaceMaterial",
    "BsdfSample",
    "ShadingFrame",
    "make_material",
    "frame_from_normal",
    "to_local",
    "to_world",
    "ggx_alpha",
    "ggx_d",
    "ggx_lambda",
    "smith_g1",
    "smith_g2_height_correlated",
    "fresnel_schlick",
    "specular_lobe_probability",
    "ggx_sample_visible_normal",
    "bsdf_eval",
    "bsdf_pdf",
    "bsdf_sample",
    "fresnel_dielectric",
    "DielectricSample",
    "rough_dielectric_sample",
]

# smallest GGX alpha: roughness 0 is a mirror with alpha raised to this, D(n) = 1 / (pi alpha^2) = 3.2e5
ALPHA_MIN = wp.constant(1.0e-3)
# smallest cosine the masking term sees: with ALPHA_MIN, f <= D V <= 3.2e5 * 2.5e9 = 8e14, finite in float32
COS_MIN = wp.constant(1.0e-7)
# the glTF dielectric's normal-incidence reflectance, ((1 - ior) / (1 + ior))^2 at ior 1.5
DIELECTRIC_F0 = wp.constant(0.04)
# directions whose squared length is outside [LEN2_MIN, LEN2_MAX] count as degenerate
LEN2_MIN = wp.constant(1.0e-30)
LEN2_MAX = wp.constant(1.0e30)
# |v|^2 within this of 1 counts as unit length (a few float32 ulps of a normalized vector)
UNIT_TOL = wp.constant(1.0e-6)


@wp.struct
class SurfaceMaterial:
    """The material at one shading point (glTF ``pbrMetallicRoughness``, all linear).

    The functions below read the fields as they are (only the roughness is clamped there): build it with
    :func:`make_material` to clamp every field.

    Attributes:
        base_color: linear RGB in [0, 1]: the diffuse albedo of the dielectric and F0 of the metal.
        metallic: in [0, 1]; 0 dielectric, 1 metal.
        roughness: glTF's perceptual roughness in [0, 1]; the GGX alpha is ``max(roughness^2, ALPHA_MIN)``.
        specular: ``KHR_materials_specular``'s ``specularFactor`` in [0, 1] (1 for the core material); it
            scales the dielectric Fresnel.
    """

    base_color: wp.vec3
    metallic: float
    roughness: float
    specular: float


@wp.struct
class BsdfSample:
    """A sampled direction: ``wi`` (local frame, unit), ``f`` = :func:`bsdf_eval` (no cosine) and ``pdf`` =
    :func:`bsdf_pdf` (solid angle) at it. ``pdf == 0`` marks a failed sample (below the surface or degenerate
    ``wo``), with ``f == 0``."""

    wi: wp.vec3
    f: wp.vec3
    pdf: float


@wp.struct
class ShadingFrame:
    """An orthonormal right-handed frame: tangent ``t``, bitangent ``b``, normal ``n`` (``t x b = n``)."""

    t: wp.vec3
    b: wp.vec3
    n: wp.vec3


@wp.func
def _unit_clamp(x: float) -> float:
    """x clamped to [0, 1]; NaN gives 0."""
    if x > 1.0:
        return 1.0
    if x >= 0.0:
        return x
    return 0.0


@wp.func
def _safe_unit(v: wp.vec3) -> wp.vec3:
    """v / |v|, or the zero vector when |v| is zero, tiny, huge, infinite or NaN. A v already of unit length
    (to UNIT_TOL in |v|^2) is returned as it is, so that evaluating a sampled direction repeats the sampler's
    arithmetic exactly (one more rounding moves the GGX peak's D by 1e-3 relatively at ALPHA_MIN)."""
    l2 = wp.dot(v, v)
    if wp.abs(l2 - 1.0) <= UNIT_TOL:
        return v
    if l2 >= LEN2_MIN and l2 <= LEN2_MAX:
        return v / wp.sqrt(l2)
    return wp.vec3(0.0, 0.0, 0.0)


@wp.func
def _luminance(c: wp.vec3) -> float:
    """Rec. 709 luminance of linear RGB."""
    return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]


@wp.func
def make_material(base_color: wp.vec3, metallic: float, roughness: float, specular: float) -> SurfaceMaterial:
    """A :class:`SurfaceMaterial` with every parameter clamped to [0, 1] (NaN to 0)."""
    m = SurfaceMaterial()
    m.base_color = wp.vec3(_unit_clamp(base_color[0]), _unit_clamp(base_color[1]), _unit_clamp(base_color[2]))
    m.metallic = _unit_clamp(metallic)
    m.roughness = _unit_clamp(roughness)
    m.specular = _unit_clamp(specular)
    return m


@wp.func
def frame_from_normal(n: wp.vec3) -> ShadingFrame:
    """An orthonormal frame around ``n`` (normalized here; a degenerate ``n`` gives the z axis), without
    branches on the normal's direction other than its z sign (Duff et al. 2017, "Building an Orthonormal Basis,
    Revisited", JCGT 6(1))."""
    u = _safe_unit(n)
    if u[2] == 0.0 and u[0] == 0.0 and u[1] == 0.0:
        u = wp.vec3(0.0, 0.0, 1.0)
    sign = 1.0
    if u[2] < 0.0:
        sign = -1.0
    a = -1.0 / (sign + u[2])
    b = u[0] * u[1] * a
    fr = ShadingFrame()
    fr.t = wp.vec3(1.0 + sign * u[0] * u[0] * a, sign * b, -sign * u[0])
    fr.b = wp.vec3(b, sign + u[1] * u[1] * a, -u[1])
    fr.n = u
    return fr


@wp.func
def to_local(fr: ShadingFrame, v: wp.vec3) -> wp.vec3:
    """World vector -> coordinates in the frame (z along ``fr.n``)."""
    return wp.vec3(wp.dot(v, fr.t), wp.dot(v, fr.b), wp.dot(v, fr.n))


@wp.func
def to_world(fr: ShadingFrame, v: wp.vec3) -> wp.vec3:
    """Coordinates in the frame -> world vector."""
    return v[0] * fr.t + v[1] * fr.b + v[2] * fr.n


@wp.func
def ggx_alpha(roughness: float) -> float:
    """glTF's perceptual roughness -> GGX alpha = roughness^2, at least ALPHA_MIN."""
    r = _unit_clamp(roughness)
    return wp.max(r * r, ALPHA_MIN)


@wp.func
def ggx_d(alpha: float, h: wp.vec3) -> float:
    """GGX normal distribution of the unit local microfacet normal ``h`` (Walter et al. 2007, eq. 33):
    ``alpha^2 / (pi (sin^2 + alpha^2 cos^2)^2)``, which is ``alpha^2 / (pi ((alpha^2 - 1) cos^2 + 1)^2)`` without
    its cancellation at cos = 1. Zero for ``h.z <= 0``."""
    if h[2] <= 0.0:
        return 0.0
    a2 = alpha * alpha
    t = h[0] * h[0] + h[1] * h[1] + a2 * h[2] * h[2]
    return a2 / (wp.pi * t * t)


@wp.func
def _smith_a(alpha: float, z: float) -> float:
    """sqrt(z^2 + alpha^2 (1 - z^2)) for a cosine z in [0, 1]: Lambda(z) = (a / z - 1) / 2."""
    z2 = z * z
    return wp.sqrt(z2 + alpha * alpha * wp.max(1.0 - z2, 0.0))


@wp.func
def ggx_lambda(alpha: float, z: float) -> float:
    """Smith's Lambda for GGX at the cosine z (Heitz 2014); z raised to COS_MIN."""
    zc = wp.clamp(z, COS_MIN, 1.0)
    return 0.5 * (_smith_a(alpha, zc) / zc - 1.0)


@wp.func
def smith_g1(alpha: float, z: float) -> float:
    """Smith masking G1 = 1 / (1 + Lambda) = 2 z / (z + a) (Heitz 2014); 0 for z <= 0."""
    if z <= 0.0:
        return 0.0
    zc = wp.min(wp.max(z, COS_MIN), 1.0)
    return 2.0 * zc / (zc + _smith_a(alpha, zc))


@wp.func
def smith_g2_height_correlated(alpha: float, zo: float, zi: float) -> float:
    """Height-correlated Smith masking-shadowing 1 / (1 + Lambda(zo) + Lambda(zi)) (Heitz 2014) for
    reflection, = 2 zo zi / (zi a_o + zo a_i); 0 when either cosine is <= 0."""
    if zo <= 0.0 or zi <= 0.0:
        return 0.0
    co = wp.min(wp.max(zo, COS_MIN), 1.0)
    ci = wp.min(wp.max(zi, COS_MIN), 1.0)
    return 2.0 * co * ci / (ci * _smith_a(alpha, co) + co * _smith_a(alpha, ci))


@wp.func
def _smith_v(alpha: float, zo: float, zi: float) -> float:
    """V = G2 / (4 zo zi) = 0.5 / (zi a_o + zo a_i) for cosines > 0, raised to COS_MIN."""
    co = wp.min(wp.max(zo, COS_MIN), 1.0)
    ci = wp.min(wp.max(zi, COS_MIN), 1.0)
    return 0.5 / (ci * _smith_a(alpha, co) + co * _smith_a(alpha, ci))


@wp.func
def fresnel_schlick(f0: wp.vec3, cos_theta: float) -> wp.vec3:
    """Schlick's Fresnel ``f0 + (1 - f0) (1 - cos)^5``, cos clamped to [0, 1]."""
    c = 1.0 - wp.clamp(cos_theta, 0.0, 1.0)
    c2 = c * c
    w = c2 * c2 * c
    return f0 + (wp.vec3(1.0, 1.0, 1.0) - f0) * w


@wp.func
def fresnel_dielectric(cos_i: float, eta: float):
    """(F, cos_t): the unpolarized Fresnel reflectance of a smooth interface and the cosine of the refracted
    direction, for light arriving at ``cos_i`` (in (0, 1], clamped) on the side of index n_i, ``eta = n_t / n_i``
    (> 0): ``F = (r_s^2 + r_p^2) / 2`` with ``r_s = (cos_i - eta cos_t) / (cos_i + eta cos_t)`` and
    ``r_p = (eta cos_i - cos_t) / (eta cos_i + cos_t)``; total internal reflection gives (1, 0)."""
    c = wp.clamp(cos_i, 0.0, 1.0)
    sin2_t = (1.0 - c * c) / (eta * eta)
    if not (sin2_t < 1.0):
        return 1.0, 0.0
    ct = wp.sqrt(1.0 - sin2_t)
    rs = (c - eta * ct) / (c + eta * ct)
    rp = (eta * c - ct) / (eta * c + ct)
    f = 0.5 * (rs * rs + rp * rp)
    if not wp.isfinite(f):  # cos_i = 0 with eta = 1
        f = 1.0
    return wp.clamp(f, 0.0, 1.0), ct


@wp.func
def _dielectric_fresnel(m: SurfaceMaterial, cos_theta: float) -> float:
    """Fd = s (0.04 + 0.96 (1 - cos)^5)."""
    c = 1.0 - wp.clamp(cos_theta, 0.0, 1.0)
    c2 = c * c
    return m.specular * (DIELECTRIC_F0 + (1.0 - DIELECTRIC_F0) * c2 * c2 * c)


@wp.func
def _specular_fresnel(m: SurfaceMaterial, cos_theta: float) -> wp.vec3:
    """F = (1 - metallic) Fd + metallic Fm: the Fresnel of the shared specular lobe."""
    fm = fresnel_schlick(m.base_color, cos_theta)
    fd = _dielectric_fresnel(m, cos_theta)
    return (1.0 - m.metallic) * wp.vec3(fd, fd, fd) + m.metallic * fm


@wp.func
def specular_lobe_probability(m: SurfaceMaterial, cos_o: float) -> float:
    """Probability of sampling the specular lobe: w_spec / (w_spec + w_diff) with the lobes' Fresnel weights at
    ``wo`` (module docstring); 1 when both are 0 (then the diffuse lobe is 0 and the specular lobe may not be,
    e.g. a black metal seen head-on)."""
    ws = _luminance(_specular_fresnel(m, cos_o))
    wd = (1.0 - m.metallic) * (1.0 - _dielectric_fresnel(m, cos_o)) * _luminance(m.base_color)
    total = ws + wd
    if total > 0.0:
        return ws / total
    return 1.0


@wp.func
def ggx_sample_visible_normal(wo: wp.vec3, alpha: float, u1: float, u2: float) -> wp.vec3:
    """A microfacet normal drawn from the GGX distribution of normals visible from the unit ``wo`` (wo.z > 0),
    isotropic alpha (Heitz 2018, JCGT 7(4)): stretch ``wo`` to the hemisphere configuration, sample
    the projected disk (a half disk rescaled towards the horizon), lift to the hemisphere, unstretch."""
    vh = _safe_unit(wp.vec3(alpha * wo[0], alpha * wo[1], wo[2]))
    len2 = vh[0] * vh[0] + vh[1] * vh[1]
    t1 = wp.vec3(1.0, 0.0, 0.0)
    if len2 > 0.0:
        t1 = wp.vec3(-vh[1], vh[0], 0.0) / wp.sqrt(len2)
    t2 = wp.cross(vh, t1)
    r = wp.sqrt(wp.clamp(u1, 0.0, 1.0))
    phi = 2.0 * wp.pi * u2
    p1 = r * wp.cos(phi)
    p2 = r * wp.sin(phi)
    s = 0.5 * (1.0 + vh[2])
    p2 = (1.0 - s) * wp.sqrt(wp.max(1.0 - p1 * p1, 0.0)) + s * p2
    nh = p1 * t1 + p2 * t2 + wp.sqrt(wp.max(1.0 - p1 * p1 - p2 * p2, 0.0)) * vh
    ne = _safe_unit(wp.vec3(alpha * nh[0], alpha * nh[1], wp.max(nh[2], 0.0)))
    if ne[2] <= 0.0:
        # the stretched normal fell on the horizon (u1 = 1 at grazing wo): the geometric normal instead
        ne = wp.vec3(0.0, 0.0, 1.0)
    return ne


@wp.func
def _pdf_lobes(m: SurfaceMaterial, wo: wp.vec3, wi: wp.vec3) -> float:
    """Mixture pdf for unit wo, wi with wo.z > 0, wi.z > 0."""
    alpha = ggx_alpha(m.roughness)
    h = _safe_unit(wo + wi)
    # D(h) G1(wo) / (4 wo.z) = D(h) / (2 (wo.z + a_o))
    co = wp.min(wp.max(wo[2], COS_MIN), 1.0)
    pdf_spec = ggx_d(alpha, h) / (2.0 * (co + _smith_a(alpha, co)))
    pdf_diff = wi[2] / wp.pi
    p = specular_lobe_probability(m, wo[2])
    return p * pdf_spec + (1.0 - p) * pdf_diff


@wp.func
def _eval_lobes(m: SurfaceMaterial, wo: wp.vec3, wi: wp.vec3) -> wp.vec3:
    """f for unit wo, wi with wo.z > 0, wi.z > 0."""
    alpha = ggx_alpha(m.roughness)
    h = _safe_unit(wo + wi)
    cos_h = wp.clamp(wp.dot(wo, h), 0.0, 1.0)
    spec = ggx_d(alpha, h) * _smith_v(alpha, wo[2], wi[2])
    f_spec = spec * _specular_fresnel(m, cos_h)
    f_diff = ((1.0 - m.metallic) * (1.0 - _dielectric_fresnel(m, cos_h)) / wp.pi) * m.base_color
    return f_spec + f_diff


@wp.func
def bsdf_eval(m: SurfaceMaterial, wo: wp.vec3, wi: wp.vec3) -> wp.vec3:
    """The BRDF value f(wo, wi) (RGB, 1/sr), WITHOUT the cosine wi.z; local frame, directions of any nonzero
    length; 0 below the surface or for degenerate directions. Reciprocal: f(wo, wi) = f(wi, wo)."""
    uo = _safe_unit(wo)
    ui = _safe_unit(wi)
    if uo[2] <= 0.0 or ui[2] <= 0.0:
        return wp.vec3(0.0, 0.0, 0.0)
    return _eval_lobes(m, uo, ui)


@wp.func
def bsdf_pdf(m: SurfaceMaterial, wo: wp.vec3, wi: wp.vec3) -> float:
    """Solid-angle density of :func:`bsdf_sample` producing ``wi`` from ``wo``: the lobe mixture; 0 below the
    surface or for degenerate directions. Over the upper hemisphere it integrates to 1 minus the mass of the
    visible-normal reflections that fall below the horizon (those samples fail, see :class:`BsdfSample`)."""
    uo = _safe_unit(wo)
    ui = _safe_unit(wi)
    if uo[2] <= 0.0 or ui[2] <= 0.0:
        return 0.0
    return _pdf_lobes(m, uo, ui)


@wp.func
def bsdf_sample(m: SurfaceMaterial, wo: wp.vec3, u1: float, u2: float, u3: float) -> BsdfSample:
    """Draw ``wi`` for ``wo`` from uniform numbers u1, u2 (the direction) and u3 (the lobe choice) in [0, 1).
    Returns ``wi``, ``f = bsdf_eval(m, wo, wi)`` and ``pdf = bsdf_pdf(m, wo, wi)``; ``pdf = 0`` (and ``f = 0``)
    when ``wo`` is below the surface or degenerate or the reflected direction falls below the surface."""
    out = BsdfSample()
    out.wi = wp.vec3(0.0, 0.0, 1.0)
    out.f = wp.vec3(0.0, 0.0, 0.0)
    out.pdf = 0.0
    uo = _safe_unit(wo)
    if uo[2] <= 0.0:
        return out
    wi = wp.vec3(0.0, 0.0, 1.0)
    if u3 < specular_lobe_probability(m, uo[2]):
        h = ggx_sample_visible_normal(uo, ggx_alpha(m.roughness), u1, u2)
        wi = _safe_unit(2.0 * wp.dot(uo, h) * h - uo)
    else:
        uc = wp.clamp(u1, 0.0, 1.0)
        r = wp.sqrt(uc)
        phi = 2.0 * wp.pi * u2
        wi = wp.vec3(r * wp.cos(phi), r * wp.sin(phi), wp.sqrt(1.0 - uc))
    out.wi = wi
    if wi[2] <= 0.0:
        return out
    out.f = _eval_lobes(m, uo, wi)
    out.pdf = _pdf_lobes(m, uo, wi)
    return out


@wp.struct
class DielectricSample:
    """A direction drawn from a rough dielectric interface: ``wi`` (local frame, unit; ``wi.z > 0`` reflected,
    ``< 0`` transmitted), ``weight`` = f |wi.z| / pdf (without the transmitted light's 1 / eta^2 radiance scale
    and tint), ``pdf`` its solid-angle density, ``transmitted`` 1 for a refraction; ``weight == 0`` marks a failed
    sample."""

    wi: wp.vec3
    weight: float
    pdf: float
    transmitted: int


@wp.func
def rough_dielectric_sample(wo: wp.vec3, alpha: float, eta: float, u1: float, u2: float,
                            u3: float) -> DielectricSample:
    """Draw ``wi`` from a GGX rough dielectric interface (Walter et al. 2007) seen from ``wo`` (local, ``wo.z > 0``
    on the side the ray arrives from; ``eta`` = the index across the interface over the index on wo's side, > 0):
    a microfacet normal ``m`` from the distribution of normals visible from ``wo`` (Heitz 2018), then reflection
    about ``m`` with the Fresnel probability ``F(wo.m)`` of :func:`fresnel_dielectric`, else refraction through it.
    With the height-correlated Smith term ``G2 = 1 / (1 + Lambda(wo) + Lambda(wi))`` for both (as pbrt-v4) the
    sample's weight ``f |wi.z| / pdf`` is ``G2 / G1(wo) = (1 + Lambda(wo)) / (1 + Lambda(wo) + Lambda(wi))`` in
    (0, 1]: the Fresnel factor and D cancel against the sampling. The pdf is the visible-normal density
    ``D_o(m) = G1(wo) (wo.m) D(m) / wo.z`` times ``F / (4 wo.m)`` for a reflection and
    ``(1 - F) eta^2 |wi.m| / (wo.m + eta wi.m)^2`` for a refraction (the Jacobians of the two half-vector maps).
    A reflection that leaves below the surface or a refraction above it fails (``weight`` 0): the light the
    microfacet model loses to multiple scattering."""
    out = DielectricSample()
    out.wi = wp.vec3(0.0, 0.0, 1.0)
    out.weight = 0.0
    out.pdf = 0.0
    out.transmitted = 0
    uo = _safe_unit(wo)
    if uo[2] <= 0.0 or not (eta > 0.0):
        return out
    m = ggx_sample_visible_normal(uo, alpha, u1, u2)
    c = wp.dot(uo, m)
    if not (c > 0.0):
        return out
    fres, ct = fresnel_dielectric(c, eta)
    lo = ggx_lambda(alpha, uo[2])
    d_vis = ggx_d(alpha, m) * c / ((1.0 + lo) * wp.max(uo[2], COS_MIN))
    wi = wp.vec3(0.0, 0.0, 1.0)
    pdf = float(0.0)
    if u3 < fres:
        wi = _safe_unit(2.0 * c * m - uo)
        if not (wi[2] > 0.0):
            return out
        pdf = fres * d_vis / (4.0 * c)
    else:
        inv = 1.0 / eta
        wi = _safe_unit(-uo * inv + m * (inv * c - ct))
        if not (wi[2] < 0.0):
            return out
        ci = wp.dot(wi, m)
        den = c + eta * ci
        pdf = (1.0 - fres) * d_vis * eta * eta * wp.abs(ci) / wp.max(den * den, 1.0e-30)
        out.transmitted = 1
    out.wi = wi
    out.weight = (1.0 + lo) / (1.0 + lo + ggx_lambda(alpha, wp.abs(wi[2])))
    out.pdf = wp.min(pdf, 1.0e30)
    return out


@wp.kernel(enable_backward=False)
def rough_dielectric_sample_kernel(wo: wp.array(dtype=wp.vec3), alpha: wp.array(dtype=float),
                                   eta: wp.array(dtype=float), u: wp.array(dtype=wp.vec3),
                                   wi: wp.array(dtype=wp.vec3), weight: wp.array(dtype=float),
                                   pdf: wp.array(dtype=float), transmitted: wp.array(dtype=int)):
    """Test hook: :func:`rough_dielectric_sample` per entry."""
    i = wp.tid()
    s = rough_dielectric_sample(wo[i], alpha[i], eta[i], u[i][0], u[i][1], u[i][2])
    wi[i] = s.wi
    weight[i] = s.weight
    pdf[i] = s.pdf
    transmitted[i] = s.transmitted
