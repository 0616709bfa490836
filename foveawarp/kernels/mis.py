"""Multiple importance sampling (Veach 1997, ch. 9): the power heuristic and a light sample's weighted
contribution, shared by the path tracer (kernels/path.py) and the textured direct integrator's environment
(kernels/shade_textured.py)."""

import warp as wp

# pdfs are raised to at most this before the power heuristic squares their ratio (a pdf of a light of area 1e-35
# would otherwise overflow float32)
PDF_MAX = wp.constant(1.0e30)


@wp.func
def power_heuristic(pa: float, pb: float) -> float:
    """Veach's power heuristic (beta = 2) of strategy a against strategy b: pa^2 / (pa^2 + pb^2), from the ratio
    of the smaller to the larger pdf so that no square overflows; 0 when pa is 0 (or NaN), 1 when pb is 0, and
    ``power_heuristic(a, b) + power_heuristic(b, a) == 1`` whenever either pdf is positive."""
    if not (pa > 0.0):
        return 0.0
    if not (pb > 0.0):
        return 1.0
    a = wp.min(pa, PDF_MAX)
    b = wp.min(pb, PDF_MAX)
    if a >= b:
        r = b / a
        return 1.0 / (1.0 + r * r)
    r = a / b
    r2 = r * r
    return r2 / (1.0 + r2)


@wp.func
def nee_weight(f: wp.vec3, cos_s: float, le: wp.vec3, pdf_light: float, pdf_bsdf: float) -> wp.vec3:
    """A sample's MIS-weighted contribution f cos Le w / pdf_light (0 for a zero pdf), w the power heuristic of
    the strategy that drew it (pdf ``pdf_light``: a light, or the BSDF for a BSDF-sampled direction) against the
    other (``pdf_bsdf``)."""
    if not (pdf_light > 0.0):
        return wp.vec3(0.0, 0.0, 0.0)
    w = power_heuristic(pdf_light, pdf_bsdf)
    return wp.cw_mul(f, le) * (cos_s * w / pdf_light)
