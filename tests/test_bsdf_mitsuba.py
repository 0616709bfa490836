"""The BSDF's GGX lobe against Mitsuba 3's ``roughconductor`` and ``roughplastic`` (variant ``scalar_rgb``).

What is comparable, and what differs by construction (all in the local frame, Mitsuba's ``si.wi`` = foveawarp's ``wo``,
Mitsuba's ``eval`` includes the cosine of the light direction, divided out here):

- D: both GGX with the same alpha (foveawarp's is ``roughness^2``): equal.
- Masking: Mitsuba multiplies separable Smith terms, ``G1(wo) G1(wi)``; foveawarp's is height-correlated,
  ``1 / (1 + Lambda_o + Lambda_i)``. Their ratio is exactly ``1 + Lambda_o Lambda_i / (1 + Lambda_o + Lambda_i)``
  (>= 1: foveawarp's lobe is never darker, and <= 1 + min(Lambda_o, Lambda_i)); it is checked to 1e-4. Its largest value
  with both cosines >= 0.5 is 1.000003, 1.0008, 1.019, 1.123 at alpha 0.05, 0.2, 0.5, 1; with both >= 0.05 it
  reaches 1.03, 1.59, 3.03, 5.51 (float64 grid of 400 x 400 cosines).
- Fresnel: Mitsuba's conductor and plastic use the exact Fresnel equations (complex ``eta + i k`` for the metal,
  ``eta = 1.5`` for the plastic's coating); foveawarp's is Schlick's with the same normal-incidence value. The exact
  Fresnel is computed here from its formula and divided out; the Schlick-vs-exact gap itself is bounded below.
- The plastic's diffuse base (internal scattering under the coating, (1 - F(wi)) (1 - F(wo)) weights) is not
  glTF's Lambert weighted by 1 - Fd(wo.h): it is switched off (``diffuse_reflectance = 0``, base colour 0 in foveawarp).
- Sampling: both draw visible normals (Heitz 2018), whose pdf ``D G1(wo) / (4 wo.z)`` holds no masking of
  ``wi``, so a metal's pdf (its specular lobe probability is 1 in foveawarp) equals Mitsuba's ``pdf``.
"""

import math

import numpy as np
import pytest
import warp as wp

from foveawarp.kernels import bsdf

mi = pytest.importorskip("mitsuba")


@pytest.fixture(scope="module")
def mitsuba_scalar():
    try:
        mi.set_variant("scalar_rgb")
    except (ImportError, AttributeError, ValueError) as e:  # a build without the scalar_rgb variant
        pytest.skip(f"mitsuba variant scalar_rgb unavailable: {e}")
    return mi


@wp.kernel(enable_backward=False)
def _eval_kernel(color: wp.vec3, met: float, rough: float, spec: float, wo: wp.array(dtype=wp.vec3),
                 wi: wp.array(dtype=wp.vec3), f: wp.array(dtype=wp.vec3), pdf: wp.array(dtype=float)):
    i = wp.tid()
    m = bsdf.make_material(color, met, rough, spec)
    f[i] = bsdf.bsdf_eval(m, wo[i], wi[i])
    pdf[i] = bsdf.bsdf_pdf(m, wo[i], wi[i])


def foveawarp_eval(device, color, met, rough, spec, wo, wi):
    n = len(wo)
    f = wp.zeros(n, dtype=wp.vec3, device=device)
    pdf = wp.zeros(n, dtype=float, device=device)
    wp.launch(_eval_kernel, dim=n, device=device,
              inputs=[wp.vec3(*color), float(met), float(rough), float(spec),
                      wp.array(wo.astype(np.float32), dtype=wp.vec3, device=device),
                      wp.array(wi.astype(np.float32), dtype=wp.vec3, device=device)], outputs=[f, pdf])
    return f.numpy().astype(np.float64), pdf.numpy().astype(np.float64)


def mitsuba_eval(m, plugin, wo, wi):
    """Mitsuba's f (cosine divided out) and pdf for each pair."""
    si = m.SurfaceInteraction3f()
    si.sh_frame = m.Frame3f(m.Vector3f(0.0, 0.0, 1.0))
    ctx = m.BSDFContext()
    f = np.zeros((len(wo), 3))
    pdf = np.zeros(len(wo))
    for k in range(len(wo)):
        si.wi = m.Vector3f(*wo[k])
        d = m.Vector3f(*wi[k])
        v = plugin.eval(ctx, si, d)
        f[k] = np.array([v[0], v[1], v[2]], np.float64) / wi[k, 2]
        pdf[k] = float(plugin.pdf(ctx, si, d))
    return f, pdf


def ggx_lambda(alpha, z):
    return 0.5 * (np.sqrt(1.0 + alpha * alpha * (1.0 - z * z) / (z * z)) - 1.0)


def masking_ratio(alpha, zo, zi):
    """height-correlated / separable Smith = (1 + Lo)(1 + Li) / (1 + Lo + Li)."""
    lo, li = ggx_lambda(alpha, zo), ggx_lambda(alpha, zi)
    return (1.0 + lo) * (1.0 + li) / (1.0 + lo + li)


def fresnel_exact(cos_i, eta):
    """Unpolarized Fresnel reflectance from vacuum into a medium of complex index eta (n + i k)."""
    eta = complex(eta)
    cos_i = np.asarray(cos_i, np.complex128)
    sin2_t = (1.0 - cos_i * cos_i) / (eta * eta)
    cos_t = np.sqrt(1.0 - sin2_t)
    r_par = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    return 0.5 * (np.abs(r_par) ** 2 + np.abs(r_perp) ** 2)


def schlick(f0, c):
    return f0 + (1.0 - f0) * (1.0 - c) ** 5


def pairs(rng, n, zmin=0.05):
    def upper():
        z = rng.uniform(zmin, 1.0, n)
        phi = rng.uniform(0.0, 2.0 * np.pi, n)
        s = np.sqrt(1.0 - z * z)
        return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)

    wo, wi = upper(), upper()
    # float32 directions, so that both renderers see the same ones
    return wo.astype(np.float32).astype(np.float64), wi.astype(np.float32).astype(np.float64)


def half_cos(wo, wi):
    h = wo + wi
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    return np.clip(np.sum(wo * h, axis=-1), 0.0, 1.0)


ALPHAS = [0.05, 0.2, 0.5, 1.0]


@pytest.mark.parametrize("alpha", ALPHAS)
def test_white_metal_matches_roughconductor_up_to_masking(device, mitsuba_scalar, alpha):
    """F = 1 on both sides (a white metal, Mitsuba's material "none"): foveawarp / Mitsuba = the masking ratio to
    1e-4, and the visible-normal pdfs are equal to 1e-4."""
    m = mitsuba_scalar
    plugin = m.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": alpha, "material": "none"})
    rng = np.random.default_rng(int(alpha * 1000))
    wo, wi = pairs(rng, 300)
    f, pdf = foveawarp_eval(device, (1.0, 1.0, 1.0), 1.0, math.sqrt(alpha), 1.0, wo, wi)
    f_mi, pdf_mi = mitsuba_eval(m, plugin, wo, wi)
    ratio = masking_ratio(alpha, wo[:, 2], wi[:, 2])
    keep = f_mi[:, 0] > 1e-6
    assert keep.mean() > 0.9
    np.testing.assert_allclose(f[keep] / f_mi[keep], np.repeat(ratio[keep, None], 3, axis=1), rtol=1e-4)
    np.testing.assert_allclose(pdf, pdf_mi, rtol=1e-4, atol=1e-6)
    lo, li = ggx_lambda(alpha, wo[:, 2]), ggx_lambda(alpha, wi[:, 2])
    assert (ratio >= 1.0).all() and (ratio <= 1.0 + np.minimum(lo, li) + 1e-12).all()
    both_high = (wo[:, 2] >= 0.5) & (wi[:, 2] >= 0.5)
    assert ratio[both_high].max() < 1.13


# a conductor with a complex index (n = 0.2, k = 3, a bright metal) and its normal-incidence reflectance
METAL_ETA, METAL_K = 0.2, 3.0
METAL_F0 = ((METAL_ETA - 1.0) ** 2 + METAL_K ** 2) / ((METAL_ETA + 1.0) ** 2 + METAL_K ** 2)


@pytest.mark.parametrize("alpha", [0.1, 0.5])
def test_metal_matches_roughconductor_up_to_fresnel_and_masking(device, mitsuba_scalar, alpha):
    """Base colour = the conductor's exact F0: foveawarp / Mitsuba = Schlick / exact Fresnel x the masking ratio
    (1e-4), at every half-vector angle."""
    m = mitsuba_scalar
    plugin = m.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": alpha,
                          "eta": METAL_ETA, "k": METAL_K})
    rng = np.random.default_rng(7)
    wo, wi = pairs(rng, 300)
    f0 = float(np.float32(METAL_F0))
    f, _ = foveawarp_eval(device, (f0, f0, f0), 1.0, math.sqrt(alpha), 1.0, wo, wi)
    f_mi, _ = mitsuba_eval(m, plugin, wo, wi)
    c = half_cos(wo, wi)
    expected = schlick(f0, c) / fresnel_exact(c, complex(METAL_ETA, METAL_K)) * masking_ratio(alpha, wo[:, 2], wi[:, 2])
    keep = f_mi[:, 0] > 1e-6
    np.testing.assert_allclose(f[keep, 0] / f_mi[keep, 0], expected[keep], rtol=1e-4)


def test_schlick_against_exact_fresnel_bound():
    """The Fresnel gap the parity above divides out (20001 cosines): for this conductor (F0 = 0.923) Schlick is
    within 1.7% of the exact reflectance at every angle (largest near 76 degrees); for the glTF dielectric
    (F0 = 0.04 against eta 1.5) within 0.036 absolute (at 85 degrees) and 23% relative (at Brewster's angle,
    55.5 degrees: exact 0.071 against Schlick's 0.055)."""
    c = np.linspace(0.0, 1.0, 20001)
    metal = np.abs(schlick(METAL_F0, c) / fresnel_exact(c, complex(METAL_ETA, METAL_K)) - 1.0)
    exact = fresnel_exact(c, 1.5)
    diel = np.abs(schlick(0.04, c) - exact)
    assert metal.max() < 0.017, metal.max()
    assert diel.max() < 0.036, diel.max()
    assert (diel / exact).max() < 0.233, (diel / exact).max()


@pytest.mark.parametrize("alpha", [0.1, 0.5])
def test_dielectric_specular_matches_roughplastic_coating(device, mitsuba_scalar, alpha):
    """The glTF dielectric with base colour 0 (no diffuse) against roughplastic with diffuse_reflectance 0 and
    eta = 1.5 (F0 = 0.04 on both sides): foveawarp / Mitsuba = Schlick(0.04) / exact Fresnel x the masking
    ratio (1e-4)."""
    m = mitsuba_scalar
    plugin = m.load_dict({"type": "roughplastic", "distribution": "ggx", "alpha": alpha, "int_ior": 1.5,
                          "ext_ior": 1.0, "diffuse_reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}})
    rng = np.random.default_rng(11)
    wo, wi = pairs(rng, 300)
    f, _ = foveawarp_eval(device, (0.0, 0.0, 0.0), 0.0, math.sqrt(alpha), 1.0, wo, wi)
    f_mi, _ = mitsuba_eval(m, plugin, wo, wi)
    c = half_cos(wo, wi)
    expected = schlick(0.04, c) / fresnel_exact(c, 1.5) * masking_ratio(alpha, wo[:, 2], wi[:, 2])
    keep = f_mi[:, 0] > 1e-6
    assert keep.mean() > 0.9
    np.testing.assert_allclose(f[keep, 0] / f_mi[keep, 0], expected[keep], rtol=1e-4)
