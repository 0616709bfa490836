"""Mitsuba scene files (``.xml``, scene versions 0.5 to 3) -> :class:`~foveawarp.io.scenedata.SceneData`.

What a direct and a path tracer need is read; everything else is named in one warning (``warnings.warn`` and
``SceneData.warnings``, one entry per kind of thing left out) and left out. Malformed XML, an unknown scene
version, a ``$parameter`` without a value, a ``ref`` to an id nothing defines and a missing referenced file
(mesh, texture, environment map, include) raise ``ValueError`` naming the file and what was wrong.

The file:
    - ``version`` 0.5.x, 0.6.x, 2.x or 3.x. Parameter names are read in Mitsuba 3's snake_case; the camelCase
      names of older versions are converted as Mitsuba 3 upgrades them (``toWorld`` -> ``to_world``,
      ``intIOR`` -> ``int_ior``).
    - ``<default name value>`` and ``$name`` in any attribute (``params`` overrides the defaults), ``<include
      filename>``, ``id`` on any element and ``<ref id>`` wherever an element may stand.
    - numbers, lists of numbers (commas and/or spaces), ``boolean``, ``string``, ``point``/``vector``
      (``x y z`` or ``value``); colours ``rgb`` (linear), ``srgb`` (decoded; ``#rrggbb`` too), ``spectrum``
      (one value; ``wavelength:value`` pairs become their mean, with a warning), ``float``.
    - ``transform``: ``matrix`` (16 numbers row-major, or 9 for the linear part), ``translate``, ``rotate``
      (axis, normalized, and angle in degrees, right-handed), ``scale`` (one ``value`` or ``x y z``), ``lookat``
      (origin, target, up: the local +z looks at the target, +y is up, +x is ``cross(up, direction)``), each op
      applied after those before it, ``M = op_n ... op_1``, as Mitsuba composes them.

Shapes (each placed by its ``to_world``; normals by the inverse transpose, the winding reversed by a mirror):
    - ``obj`` (:func:`foveawarp.io.obj.parse_obj`; UVs flipped to the top-left origin unless
      ``flip_tex_coords`` is false, as Mitsuba does), ``ply`` (positions and normals; no UVs); both with
      ``face_normals`` (flat shading) and ``flip_normals``.
    - ``rectangle`` ([-1, 1]^2 at z = 0, normal +z, uv = ((x + 1) / 2, (y + 1) / 2)), ``disk`` (unit disk at z = 0,
      normal +z, 128 segments, uv = (r, phi / 2 pi)), ``cube`` ([-1, 1]^3, 4 vertices per face, uv 0..1 per face
      in a layout of its own, not Mitsuba's),
      ``sphere`` (``center``, ``radius``, a negative one turning the normals inward as in Mitsuba; 96 x 48 quads
      in latitude-longitude about local z, uv = (phi / 2 pi, theta / pi); its vertices lie on the sphere and its
      flat facets at most 0.054 % of the radius inside).
    - an ``area`` emitter on a shape: the shape's material emits ``radiance`` (``SceneData`` convention:
      :func:`~foveawarp.io.scenedata.emission_material`).

BSDFs -> :class:`foveawarp.materials.Material` (glTF metallic-roughness; GGX roughness = sqrt(alpha)):
    - ``diffuse``: base colour ``reflectance`` (default 0.5), metallic 0, roughness 1.
    - ``plastic`` / ``roughplastic``: base colour ``diffuse_reflectance`` (default 0.5), metallic 0, roughness
      0 / sqrt(``alpha``) (default alpha 0.1); the model's dielectric F0 is 0.04 (IOR 1.5) whatever ``int_ior``
      says, and ``specular_reflectance`` is not modelled.
    - ``conductor`` / ``roughconductor``: metallic 1, roughness 0 / sqrt(``alpha``) (default 0.1; anisotropic
      ``alpha_u``, ``alpha_v``: their geometric mean, with a warning); base colour = ``specular_reflectance``
      times the normal-incidence Fresnel reflectance ``((eta - 1)^2 + k^2) / ((eta + 1)^2 + k^2)`` of ``eta``,
      ``k`` when given, else of the named ``material`` (:data:`CONDUCTOR_F0`; default "Cu" before version 2,
      "none", a perfect mirror, from version 2 on, as in Mitsuba).
    - ``dielectric`` / ``roughdielectric``: glass (``transmission_factor`` 1, ``ior`` = ``int_ior`` /
      ``ext_ior``, numbers or Mitsuba's named media, default bk7 / air; base colour ``specular_transmittance``;
      double-sided; roughness 0 / sqrt(``alpha``), default alpha 0.1, Beckmann read as GGX as for the
      conductors), refracted by the path integrator (a GGX interface where rough) and shown by its surface
      reflection by the direct one (a note).
      ``thindielectric``: a fully transparent cut-out (alpha 0, mode MASK): a thin pane lets the light through
      unbent, and its 4-8 % reflection is lost (warning).
    - ``principled`` (version 3): ``base_color``, ``metallic`` (default 0), ``roughness`` (default 0.5, the same
      perceptual roughness as glTF's); its specular, sheen, clearcoat and transmission lobes are not modelled.
    - ``twosided``: its BSDF, double-sided (every other BSDF is single-sided, except the dielectrics).
    - ``mask``: ``opacity`` as a constant (base colour alpha, mode BLEND below 1) or a bitmap that is the base
      colour texture's own file (its alpha channel is the mask, mode MASK at 0.5); any other mask texture is
      dropped (warning).
    - ``normalmap``: the ``normalmap`` bitmap as the tangent-space normal map (read as glTF's convention);
      ``bumpmap``: its BSDF, the height map dropped (warning).
    - ``bitmap`` textures: ``filename`` (PNG, JPEG, WebP), ``filter_type`` (nearest, or linear for bilinear /
      trilinear / EWA), ``wrap_mode`` (repeat, mirror, clamp; zero and one become clamp with a warning),
      ``raw`` / version 0.5's ``gamma`` (an sRGB base colour read raw is taken as sRGB, with a warning), the
      ``to_uv`` scale and offset and version 0.5's ``uscale``/``vscale``/``uoffset``/``voffset``.
    - a shape without a BSDF gets Mitsuba's default, a single-sided diffuse of reflectance 0.5.
    - a base colour outside [0, 1] (Mitsuba renders it as given) is clamped to it, with a warning; a negative
      ``alpha`` is a ``ValueError``.

Emitters -> :class:`~foveawarp.io.scenedata.LightData` / :class:`~foveawarp.io.scenedata.EnvironmentData`:
    ``point`` (``position`` or ``to_world``, ``intensity`` W/sr), ``spot`` (``to_world`` along local +z,
    ``intensity``, ``cutoff_angle`` default 20 degrees, ``beam_width`` default 3/4 of it, a linear ramp in the
    angle), ``directional`` (``direction`` or the ``to_world`` +z, ``irradiance``), ``envmap`` (``filename``
    .hdr / .exr, ``scale``, the rotation of ``to_world``), ``constant`` (``radiance`` as a 1 x 1 map).

Sensors: ``perspective`` (and ``thinlens`` as a pinhole, with a warning) -> :class:`CameraData`: eye = the
``to_world`` origin, forward its +z, up its +y, the image's right ``-x`` (a mirroring ``to_world`` cannot be
shown and is warned about); ``fov`` along ``fov_axis`` x (default), y, diagonal, smaller or larger (or
``focal_length`` on a 36 mm wide film), converted to the vertical field of view of the film's aspect;
``near_clip``, ``far_clip``; the film's ``width`` and ``height`` (default 768 x 576) -> ``SceneData.film_size``.
"""

from __future__ import annotations

import math
import re
import warnings
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path
from typing import Optional

import numpy as np

from ..config import show
from ..materials import ImageSource, Material, TextureRef
from .geometry import complete_tangents, compute_normals, face_normals, split_flat, transform_mesh
from .scenedata import CameraData, EnvironmentData, LightData, SceneData, ShapeData, emission_material

__all__ = ["read_mitsuba", "mitsuba_transform", "fov_y_deg", "CONDUCTOR_F0", "SPHERE_SEGMENTS", "DISK_SEGMENTS"]

SPHERE_SEGMENTS = (96, 48)  # (longitude, latitude) quads of a tessellated sphere: facets <= 0.054 % of r inside
DISK_SEGMENTS = 128
_MIME_BY_SUFFIX = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".webp": "image/webp"}

# Mitsuba 3's dielectric defaults ("bk7" inside, "air" outside) and some of its named media
MITSUBA_INT_IOR = 1.5046
MITSUBA_EXT_IOR = 1.000277
MITSUBA_NAMED_IOR = {"vacuum": 1.0, "air": 1.000277, "water": 1.3330, "water ice": 1.31, "acetone": 1.36,
                     "ethanol": 1.361, "glycerol": 1.4729, "fused quartz": 1.458, "pyrex": 1.470,
                     "acrylic glass": 1.49, "polypropylene": 1.49, "bk7": 1.5046, "sodium chloride": 1.544,
                     "amber": 1.55, "pet": 1.575, "diamond": 2.419}

# normal-incidence reflectance (linear RGB) of Mitsuba 3's named conductors, from its scalar_rgb eta and k
CONDUCTOR_F0 = {
    "none": (1.0, 1.0, 1.0),
    "a-C": (0.279, 0.194, 0.169), "Ag": (0.975, 0.958, 0.906), "Al": (0.928, 0.918, 0.919),
    "AlAs": (0.320, 0.278, 0.143), "AlAs_palik": (0.320, 0.278, 0.143), "Au": (0.967, 0.802, 0.324),
    "Be": (0.598, 0.521, 0.506), "Cr": (0.688, 0.649, 0.687), "CsI": (0.133, 0.068, 0.062),
    "Cu": (0.952, 0.620, 0.511), "Cu2O": (0.315, 0.246, 0.238), "CuO": (0.291, 0.198, 0.183),
    "d-C": (0.212, 0.158, 0.145), "Hg": (0.814, 0.770, 0.763), "HgTe": (0.470, 0.367, 0.351),
    "Ir": (0.743, 0.680, 0.631), "K": (0.954, 0.936, 0.920), "Li": (0.925, 0.884, 0.793),
    "MgO": (0.124, 0.060, 0.053), "Mo": (0.618, 0.562, 0.541), "Na_palik": (0.979, 0.960, 0.932),
    "Nb": (0.564, 0.490, 0.473), "Ni_palik": (0.700, 0.594, 0.494), "Rh": (0.824, 0.754, 0.722),
    "Se": (0.379, 0.251, 0.241), "SiC": (0.271, 0.187, 0.181), "SnTe": (0.407, 0.108, 0.015),
    "Ta": (0.457, 0.342, 0.380), "Te": (0.635, 0.578, 0.562), "ThF4": (0.086, 0.033, 0.026),
    "TiC": (0.548, 0.440, 0.412), "TiN": (0.641, 0.452, 0.198), "TiO2": (0.304, 0.225, 0.238),
    "VC": (0.530, 0.418, 0.380), "V_palik": (0.573, 0.511, 0.537), "VN": (0.525, 0.393, 0.311),
    "W": (0.575, 0.478, 0.433),
}

_PARAM_TAGS = ("float", "integer", "boolean", "string", "point", "vector", "rgb", "srgb", "spectrum",
               "blackbody", "transform", "texture", "ref", "bsdf", "emitter", "sensor", "film", "rfilter",
               "sampler", "medium", "phase", "shape", "volume")
_SILENT_TOP = ("integrator", "sampler", "rfilter", "default", "include")
_CAMEL = re.compile(r"([a-z0-9])([A-Z])")
_SUBST = re.compile(r"\$([A-Za-z_][A-Za-z0-9_]*)")


def _snake(name: str) -> str:
    return _CAMEL.sub(r"\1_\2", name).lower()


class _Fail(Exception):
    pass


class _Reader:
    """State of one read: the file, the id table, the notes (left out / approximated) and the outputs."""

    def __init__(self, path: Path, version: tuple):
        self.path = path
        self.version = version
        self.ids: dict = {}
        self.notes: dict = {}  # message -> count
        self.images: list = []
        self.image_index: dict = {}
        self.materials: list = []
        self.material_of: dict = {}  # id(element) -> material index
        self.mesh_cache: dict = {}

    def fail(self, what: str):
        raise ValueError(f"Mitsuba scene {str(self.path)!r}: {what}")

    def note(self, what: str):
        self.notes[what] = self.notes.get(what, 0) + 1

    # -- elements --------------------------------------------------------------------------------------------
    def resolve(self, el: ET.Element) -> ET.Element:
        """``el``, or the element a ``<ref id>`` names."""
        if el.tag != "ref":
            return el
        rid = el.get("id")
        if rid is None:
            self.fail("a <ref> element has no id attribute")
        if rid not in self.ids:
            self.fail(f"<ref id={rid!r}> names an id that no element defines (ids: {sorted(self.ids)[:20]})")
        return self.ids[rid]

    def label(self, el: ET.Element) -> str:
        parts = [el.tag]
        if el.get("type"):
            parts.append(f"type={el.get('type')!r}")
        if el.get("id"):
            parts.append(f"id={el.get('id')!r}")
        if el.get("name"):
            parts.append(f"name={el.get('name')!r}")
        return "<" + " ".join(parts) + ">"

    def params(self, el: ET.Element) -> dict:
        """{snake_case name: child element} of the named children of ``el`` (refs resolved)."""
        out = {}
        for c in el:
            n = c.get("name")
            if n is not None:
                out[_snake(n)] = c
        return out

    def children(self, el: ET.Element, tag: str) -> list:
        """The children of ``el`` that are (or refer to) ``tag`` elements."""
        out = []
        for c in el:
            r = self.resolve(c) if c.tag == "ref" else c
            if r.tag == tag:
                out.append(r)
        return out

    def numbers(self, el: ET.Element, text: str, what: str) -> list:
        try:
            return [float(t) for t in re.split(r"[,\s]+", text.strip()) if t]
        except ValueError:
            self.fail(f"{self.label(el)}: {what} must be numbers, got {text!r}")

    def value(self, el: ET.Element, attr: str = "value") -> str:
        v = el.get(attr)
        if v is None:
            self.fail(f"{self.label(el)} needs a {attr!r} attribute")
        return v

    def float_of(self, el: Optional[ET.Element], default: float) -> float:
        if el is None:
            return default
        el = self.resolve(el)
        if el.tag in ("float", "integer"):
            nums = self.numbers(el, self.value(el), "value")
            if len(nums) != 1 or not math.isfinite(nums[0]):
                self.fail(f"{self.label(el)}: value must be one finite number, got {el.get('value')!r}")
            return nums[0]
        if el.tag in ("rgb", "srgb", "spectrum"):
            return float(np.mean(self.color_of(el, (default,) * 3)))
        self.note(f"{self.label(el)} where a number is expected (the default {default:g} is used)")
        return default

    def ior_of(self, el: Optional[ET.Element], default: float) -> float:
        """An index of refraction: a number, or one of Mitsuba's named media (:data:`MITSUBA_NAMED_IOR`)."""
        if el is not None and self.resolve(el).tag == "string":
            n = self.string_of(el, None)
            if n not in MITSUBA_NAMED_IOR:
                self.note(f"{self.label(el)}: index of refraction {n!r} (not a known medium: {default:g} is used)")
                return default
            return MITSUBA_NAMED_IOR[n]
        v = self.float_of(el, default)
        if not v > 0.0:
            self.fail(f"{self.label(el)}: an index of refraction must be > 0, got {v!r}")
        return v

    def bool_of(self, el: Optional[ET.Element], default: bool) -> bool:
        if el is None:
            return default
        v = self.value(self.resolve(el)).strip().lower()
        if v not in ("true", "false"):
            self.fail(f"{self.label(el)}: value must be true or false, got {v!r}")
        return v == "true"

    def string_of(self, el: Optional[ET.Element], default: Optional[str]) -> Optional[str]:
        return default if el is None else self.value(self.resolve(el))

    def vec3_of(self, el: ET.Element) -> np.ndarray:
        if el.get("value") is not None:
            nums = self.numbers(el, el.get("value"), "value")
            if len(nums) == 1:
                nums = nums * 3
        else:
            nums = [self.numbers(el, el.get(k, "0"), k)[0] for k in ("x", "y", "z")]
        if len(nums) != 3 or not all(math.isfinite(x) for x in nums):
            self.fail(f"{self.label(el)}: needs 3 finite numbers, got {el.attrib}")
        return np.array(nums, dtype=np.float64)

    def color_of(self, el: Optional[ET.Element], default) -> tuple:
        """A constant colour (linear RGB) of an rgb / srgb / spectrum / float element."""
        if el is None:
            return tuple(float(c) for c in default)
        el = self.resolve(el)
        tag = el.tag
        if tag in ("float", "integer"):
            return (self.float_of(el, 0.0),) * 3
        if tag in ("rgb", "srgb"):
            text = self.value(el).strip()
            if text.startswith("#"):
                h = text[1:]
                if len(h) != 6 or not all(ch in "0123456789abcdefABCDEF" for ch in h):
                    self.fail(f"{self.label(el)}: a colour '#rrggbb' was expected, got {text!r}")
                nums = [int(h[i:i + 2], 16) / 255.0 for i in (0, 2, 4)]
            else:
                nums = self.numbers(el, text, "value")
            if len(nums) == 1:
                nums = nums * 3
            if len(nums) != 3 or not all(math.isfinite(x) for x in nums):
                self.fail(f"{self.label(el)}: value must be 1 or 3 finite numbers, got {text!r}")
            if tag == "srgb":
                from .images import srgb_to_linear

                nums = [float(x) for x in srgb_to_linear(np.clip(np.array(nums), 0.0, 1.0))]
            return tuple(float(x) for x in nums)
        if tag == "spectrum":
            if el.get("filename") is not None:
                self.note(f"{self.label(el)} from a spectrum file (the default {default} is used)")
                return tuple(float(c) for c in default)
            text = self.value(el)
            if ":" in text:
                pairs = [p.split(":") for p in re.split(r"[,\s]+", text.strip()) if p]
                try:
                    vals = [float(b) for _, b in pairs]
                except ValueError:
                    self.fail(f"{self.label(el)}: wavelength:value pairs expected, got {text!r}")
                self.note("spectra given per wavelength, taken as their mean (grey)")
                return (float(np.mean(vals)),) * 3
            nums = self.numbers(el, text, "value")
            if len(nums) != 1:
                self.fail(f"{self.label(el)}: value must be one number or wavelength:value pairs, got {text!r}")
            return (nums[0],) * 3
        if tag == "blackbody":
            self.note(f"{self.label(el)} (a blackbody spectrum is not supported; the default is used)")
            return tuple(float(c) for c in default)
        if tag == "texture":
            self.note(f"{self.label(el)} where a constant colour is needed (the default {default} is used)")
            return tuple(float(c) for c in default)
        self.fail(f"{self.label(el)} cannot give a colour")

    # -- transforms ------------------------------------------------------------------------------------------
    def transform_of(self, el: Optional[ET.Element]) -> np.ndarray:
        if el is None:
            return np.eye(4)
        el = self.resolve(el)
        if el.tag != "transform":
            self.fail(f"{self.label(el)} where a <transform> is expected")
        m = np.eye(4)
        for op in el:
            m = self.transform_op(op) @ m
        if not np.isfinite(m).all():
            self.fail(f"{self.label(el)} is not finite")
        return m

    def transform_op(self, op: ET.Element) -> np.ndarray:
        tag = op.tag.lower()
        if tag == "matrix":
            nums = self.numbers(op, self.value(op), "matrix value")
            if len(nums) == 16:
                return np.array(nums, dtype=np.float64).reshape(4, 4)
            if len(nums) == 9:
                m = np.eye(4)
                m[:3, :3] = np.array(nums).reshape(3, 3)
                return m
            self.fail(f"{self.label(op)}: value must be 16 (or 9) numbers, got {len(nums)}")
        if tag == "translate":
            m = np.eye(4)
            m[:3, 3] = self.vec3_of(op)
            return m
        if tag == "scale":
            if op.get("value") is not None:
                s = self.vec3_of(op)
            else:
                s = np.array([self.numbers(op, op.get(k, "1"), k)[0] for k in ("x", "y", "z")])
            return np.diag([s[0], s[1], s[2], 1.0])
        if tag == "rotate":
            if op.get("angle") is None:
                self.fail(f"{self.label(op)}: needs an angle (degrees)")
            angle = self.numbers(op, op.get("angle"), "angle")[0]
            axis = self.vec3_of(op)
            return _rotation(axis, angle, self, op)
        if tag == "lookat":
            origin = self.numbers(op, self.value(op, "origin"), "origin")
            target = self.numbers(op, self.value(op, "target"), "target")
            up = self.numbers(op, op.get("up", "0 1 0"), "up")
            if len(origin) != 3 or len(target) != 3 or len(up) != 3:
                self.fail(f"{self.label(op)}: origin, target and up need 3 numbers each")
            return _look_at(np.array(origin), np.array(target), np.array(up), self, op)
        self.note(f"transform operation <{op.tag}>")
        return np.eye(4)

    # -- textures and materials ------------------------------------------------------------------------------
    def image(self, el: ET.Element, filename: str) -> int:
        p = self.file(el, filename)
        if p.suffix.lower() not in _MIME_BY_SUFFIX:
            return -1
        key = p.resolve()
        if key not in self.image_index:
            self.image_index[key] = len(self.images)
            self.images.append(ImageSource(name=str(p), path=p, mime_type=_MIME_BY_SUFFIX[p.suffix.lower()]))
        return self.image_index[key]

    def file(self, el: ET.Element, filename: str) -> Path:
        p = self.path.parent / filename.replace("\\", "/")
        if not p.is_file():
            self.fail(f"{self.label(el)} refers to the file {filename!r}, which does not exist (looked for {p})")
        return p

    def bitmap(self, el: ET.Element, color_space: str, slot: str) -> Optional[TextureRef]:
        """A ``bitmap`` texture element -> TextureRef (None, with a note, for what cannot be one)."""
        el = self.resolve(el)
        if el.tag != "texture":
            return None
        kind = el.get("type")
        if kind != "bitmap":
            self.note(f"texture type {kind!r} (its parameter takes its default)")
            return None
        p = self.params(el)
        filename = self.string_of(p.get("filename"), None)
        if filename is None:
            self.fail(f"{self.label(el)} has no filename")
        img = self.image(el, filename)
        if img < 0:
            self.note(f"bitmap {filename!r}: only PNG, JPEG and WebP textures are read (its parameter takes its "
                      f"default)")
            return None
        filt = (self.string_of(p.get("filter_type"), "bilinear") or "bilinear").lower()
        filt = "nearest" if filt == "nearest" else "linear"
        wraps = []
        base_wrap = (self.string_of(p.get("wrap_mode"), "repeat") or "repeat").lower()
        for axis in ("u", "v"):
            w = (self.string_of(p.get(f"wrap_mode_{axis}"), base_wrap) or base_wrap).lower()
            if w in ("zero", "one"):
                self.note(f"bitmap wrap mode {w!r} (read as clamp)")
                w = "clamp"
            if w not in ("repeat", "mirror", "clamp"):
                self.note(f"bitmap wrap mode {w!r} (read as repeat)")
                w = "repeat"
            wraps.append(w)
        raw = self.bool_of(p.get("raw"), False)
        if "gamma" in p:
            raw = raw or abs(self.float_of(p["gamma"], -1.0) - 1.0) < 1e-6
        if raw and color_space == "srgb":
            self.note(f"a raw (linear) bitmap as {slot} (read as sRGB, the colour space of that slot)")
        su, sv = self.float_of(p.get("uscale"), 1.0), self.float_of(p.get("vscale"), 1.0)
        ou, ov = self.float_of(p.get("uoffset"), 0.0), self.float_of(p.get("voffset"), 0.0)
        if "to_uv" in p:
            m = self.transform_of(p["to_uv"])
            if abs(m[0, 1]) > 1e-9 or abs(m[1, 0]) > 1e-9:
                self.note("a rotated or sheared bitmap to_uv (its rotation is dropped)")
            su, sv, ou, ov = su * m[0, 0], sv * m[1, 1], ou * m[0, 0] + m[0, 3], ov * m[1, 1] + m[1, 3]
        for k in p:
            if k not in ("filename", "filter_type", "wrap_mode", "wrap_mode_u", "wrap_mode_v", "raw", "gamma",
                         "uscale", "vscale", "uoffset", "voffset", "to_uv", "max_anisotropy", "cache"):
                self.note(f"bitmap parameter {k!r}")
        return TextureRef(image=img, wrap_s=wraps[0], wrap_t=wraps[1], filter=filt, color_space=color_space,
                          uv_offset=(ou, ov), uv_scale=(su, sv))

    def colour_param(self, el: Optional[ET.Element], default, slot: str) -> tuple:
        """(linear RGB factor, TextureRef or None) of a colour parameter that may be a bitmap."""
        if el is None:
            return tuple(default), None
        r = self.resolve(el)
        if r.tag == "texture":
            t = self.bitmap(r, "srgb", slot)
            return ((1.0, 1.0, 1.0), t) if t is not None else (tuple(default), None)
        return self.color_of(r, default), None

    def rgba(self, col, what: str) -> tuple:
        """A base colour in [0, 1] (opaque); a channel outside is clamped and named in the warning."""
        out = tuple(min(1.0, max(0.0, float(c))) for c in col[:3])
        if out != tuple(float(c) for c in col[:3]):
            self.note(f"{what}: a colour outside [0, 1] (clamped)")
        return out + (1.0,)

    def alpha_param(self, p: dict, what: str) -> float:
        if "alpha_u" in p or "alpha_v" in p:
            au, av = self.float_of(p.get("alpha_u"), 0.1), self.float_of(p.get("alpha_v"), 0.1)
            if abs(au - av) > 1e-9:
                self.note(f"anisotropic roughness of {what} (the geometric mean of alpha_u and alpha_v is used)")
            if au < 0.0 or av < 0.0:
                self.fail(f"{what}: alpha_u and alpha_v must be >= 0, got {au:g} and {av:g}")
            a = math.sqrt(au * av)
        else:
            el = p.get("alpha")
            if el is not None and self.resolve(el).tag == "texture":
                self.note(f"a textured alpha of {what} (alpha 0.1 is used)")
                a = 0.1
            else:
                a = self.float_of(el, 0.1)
                if a < 0.0:
                    self.fail(f"{what}: alpha must be >= 0, got {a:g}")
        return min(1.0, math.sqrt(a))

    def material(self, el: Optional[ET.Element]) -> int:
        """The material index of a BSDF element (one per element; None: Mitsuba's default diffuse)."""
        key = None if el is None else id(el)
        if key not in self.material_of:
            if el is None:
                mat = Material(name="default", base_color_factor=(0.5, 0.5, 0.5, 1.0), metallic_factor=0.0,
                               roughness_factor=1.0, double_sided=False)
            else:
                mat = self.bsdf(el, el.get("id") or el.get("type") or "bsdf", 0)
            self.material_of[key] = len(self.materials)
            self.materials.append(mat)
        return self.material_of[key]

    def bsdf(self, el: ET.Element, name: str, depth: int) -> Material:
        el = self.resolve(el)
        if el.tag != "bsdf":
            self.fail(f"{self.label(el)} where a <bsdf> is expected")
        if depth > 16:
            self.fail(f"BSDF {name!r} nests more than 16 BSDFs")
        kind = el.get("type")
        p = self.params(el)
        what = f"bsdf {name!r} ({kind})"
        used = set()

        def get(k):
            used.add(k)
            return p.get(k)

        def inner() -> Material:
            kids = self.children(el, "bsdf")
            if not kids:
                self.note(f"{what} without a nested BSDF (the default diffuse is used)")
                return Material(name=name, base_color_factor=(0.5, 0.5, 0.5, 1.0), metallic_factor=0.0)
            if len(kids) > 1:
                self.note(f"{what}: only its first nested BSDF is used")
            return self.bsdf(kids[0], name, depth + 1)

        if kind == "diffuse":
            col, tex = self.colour_param(get("reflectance"), (0.5, 0.5, 0.5), "base colour")
            mat = Material(name=name, base_color_factor=self.rgba(col, what),
                           base_color_texture=tex, metallic_factor=0.0,
                           roughness_factor=1.0)
        elif kind in ("plastic", "roughplastic"):
            col, tex = self.colour_param(get("diffuse_reflectance"), (0.5, 0.5, 0.5), "base colour")
            rough = self.alpha_param({k: get(k) for k in ("alpha", "alpha_u", "alpha_v") if k in p}, what) \
                if kind == "roughplastic" else 0.0
            used.update(("int_ior", "ext_ior", "distribution", "nonlinear", "specular_reflectance",
                         "sample_visible"))
            mat = Material(name=name, base_color_factor=self.rgba(col, what),
                           base_color_texture=tex, metallic_factor=0.0,
                           roughness_factor=rough)
        elif kind in ("conductor", "roughconductor"):
            spec, stex = self.colour_param(get("specular_reflectance"), (1.0, 1.0, 1.0), "base colour")
            if "eta" in p or "k" in p:
                eta = np.array(self.color_of(get("eta"), (0.0, 0.0, 0.0)))
                k = np.array(self.color_of(get("k"), (1.0, 1.0, 1.0)))
                f0 = tuple(float(x) for x in ((eta - 1.0) ** 2 + k ** 2) / np.maximum((eta + 1.0) ** 2 + k ** 2,
                                                                                        1e-30))
                get("material")
            else:
                mname = self.string_of(get("material"), "Cu" if self.version[0] < 2 else "none")
                if mname not in CONDUCTOR_F0:
                    self.note(f"conductor material {mname!r} (read as a perfect mirror, 'none')")
                    mname = "none"
                f0 = CONDUCTOR_F0[mname]
            rough = self.alpha_param({k: get(k) for k in ("alpha", "alpha_u", "alpha_v") if k in p}, what) \
                if kind == "roughconductor" else 0.0
            used.update(("ext_eta", "distribution", "sample_visible"))
            mat = Material(name=name, base_color_factor=self.rgba(tuple(a * b for a, b in zip(spec, f0)), what),
                           base_color_texture=stex, metallic_factor=1.0, roughness_factor=rough)
        elif kind in ("dielectric", "roughdielectric"):
            rough = self.alpha_param({k: get(k) for k in ("alpha", "alpha_u", "alpha_v") if k in p}, what) \
                if kind == "roughdielectric" else 0.0
            ior = self.ior_of(get("int_ior"), MITSUBA_INT_IOR) / self.ior_of(get("ext_ior"), MITSUBA_EXT_IOR)
            if not 1.0 <= ior <= 5.0:
                self.note(f"{what}: relative index of refraction {ior:g} (outside [1, 5], clamped)")
                ior = min(max(ior, 1.0), 5.0)
            tint, ttex = self.colour_param(get("specular_transmittance"), (1.0, 1.0, 1.0), "transmittance")
            if ttex is not None:
                self.note(f"{what}: a textured specular_transmittance (read as 1)")
            used.update(("distribution", "specular_reflectance", "sample_visible"))
            self.note(f"{kind} BSDFs (path integrator: refracting glass; direct integrator: its surface "
                      f"reflection only)")
            mat = Material(name=name, base_color_factor=self.rgba(tint, what),
                           metallic_factor=0.0, roughness_factor=rough,
                           double_sided=True, transmission_factor=1.0, ior=ior)
        elif kind == "thindielectric":
            used.update(("int_ior", "ext_ior", "specular_reflectance", "specular_transmittance"))
            self.note("thindielectric BSDFs (fully transparent cut-outs: their reflection is lost)")
            mat = Material(name=name, base_color_factor=(1.0, 1.0, 1.0, 0.0), metallic_factor=0.0,
                           roughness_factor=0.0, alpha_mode="MASK", double_sided=True)
        elif kind == "principled":
            col, tex = self.colour_param(get("base_color"), (0.5, 0.5, 0.5), "base colour")
            vals = []
            for k, default in (("metallic", 0.0), ("roughness", 0.5)):
                el_k = get(k)
                if el_k is not None and self.resolve(el_k).tag == "texture":
                    self.note(f"a textured {k} of {what} ({default} is used)")
                    vals.append(default)
                else:
                    vals.append(min(1.0, max(0.0, self.float_of(el_k, default))))
            used.update(("specular", "spec_tint", "anisotropic", "sheen", "sheen_tint", "clearcoat",
                         "clearcoat_gloss", "spec_trans", "eta", "sample_visible"))
            mat = Material(name=name, base_color_factor=self.rgba(col, what),
                           base_color_texture=tex, metallic_factor=vals[0],
                           roughness_factor=vals[1])
        elif kind == "twosided":
            mat = replace(inner(), double_sided=True)
        elif kind == "mask":
            mat = inner()
            op = get("opacity")
            r = None if op is None else self.resolve(op)
            if r is not None and r.tag == "texture":
                t = self.bitmap(r, "srgb", "mask")
                base = mat.base_color_texture
                if t is not None and base is not None and t.image == base.image:
                    mat = replace(mat, alpha_mode="MASK", alpha_cutoff=0.5)
                elif t is not None:
                    self.note(f"{what}: an opacity bitmap that is not its base colour texture (the mask is "
                              f"dropped)")
            else:
                a = min(1.0, max(0.0, self.float_of(r, 0.5)))
                bc = mat.base_color_factor
                mat = replace(mat, base_color_factor=(bc[0], bc[1], bc[2], a),
                              alpha_mode="BLEND" if a < 1.0 else mat.alpha_mode)
        elif kind == "normalmap":
            mat = inner()
            nm = get("normalmap")
            t = self.bitmap(nm, "linear", "normal map") if nm is not None else None
            if t is None and nm is None:
                self.note(f"{what} without a normalmap texture")
            mat = replace(mat, normal_texture=t) if t is not None else mat
        elif kind == "bumpmap":
            mat = inner()
            used.update(p)
            self.note("bumpmap BSDFs (height maps are not supported; the BSDF is used without it)")
        else:
            self.note(f"BSDF type {kind!r} (a diffuse of reflectance 0.5 is used)")
            return Material(name=name, base_color_factor=(0.5, 0.5, 0.5, 1.0), metallic_factor=0.0)
        for k in sorted(set(p) - used):
            if self.resolve(p[k]).tag != "bsdf":
                self.note(f"{kind} parameter {k!r}")
        return replace(mat, name=name)




def _rotation(axis: np.ndarray, angle_deg: float, rd: _Reader, el) -> np.ndarray:
    """The right-handed rotation by ``angle_deg`` about ``axis`` (Rodrigues' formula)."""
    n = float(np.linalg.norm(axis))
    if not n > 0:
        rd.fail(f"{rd.label(el)}: the rotation axis is zero")
    x, y, z = axis / n
    a = math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    m = np.eye(4)
    m[:3, :3] = np.eye(3) + s * k + (1.0 - c) * (k @ k)
    return m


def _look_at(origin, target, up, rd: _Reader, el) -> np.ndarray:
    """Local +z towards ``target``, +x = cross(up, direction) normalized, +y = cross(z, x), origin at ``origin``."""
    d = target - origin
    if not np.linalg.norm(d) > 0:
        rd.fail(f"{rd.label(el)}: origin and target coincide")
    d = d / np.linalg.norm(d)
    left = np.cross(up, d)
    if not np.linalg.norm(left) > 1e-12:
        rd.fail(f"{rd.label(el)}: up is parallel to the view direction")
    left /= np.linalg.norm(left)
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, origin
    return m


def mitsuba_transform(xml_text: str) -> np.ndarray:
    """The 4x4 matrix of one ``<transform>`` element given as XML text (the reader's composition rules)."""
    el = ET.fromstring(xml_text)
    rd = _Reader(Path("<transform>"), (3, 0, 0))
    return rd.transform_of(el)


def fov_y_deg(fov_deg: float, fov_axis: str, aspect: float) -> float:
    """The vertical field of view (degrees) of a Mitsuba ``fov`` along ``fov_axis`` (x, y, diagonal, smaller,
    larger) on a film of ``aspect`` = width / height."""
    axis = fov_axis.lower()
    if axis == "smaller":
        axis = "y" if aspect > 1.0 else "x"
    elif axis == "larger":
        axis = "x" if aspect > 1.0 else "y"
    t = math.tan(math.radians(fov_deg) / 2.0)
    if axis == "x":
        ty = t / aspect
    elif axis == "y":
        ty = t
    elif axis == "diagonal":
        ty = t / math.sqrt(aspect * aspect + 1.0)
    else:
        raise ValueError(f"fov_axis must be one of ['x', 'y', 'diagonal', 'smaller', 'larger'], got {fov_axis!r}")
    return math.degrees(2.0 * math.atan(ty))


# ---------------------------------------------------------------------------------------------------------------
# shapes in their local frames: (positions, normals, uvs, triangles)


def _rectangle():
    p = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    n = np.tile([0.0, 0.0, 1.0], (4, 1))
    uv = (p[:, :2] + 1.0) / 2.0
    return p, n, uv, np.array([[0, 1, 2], [0, 2, 3]])


def _cube():
    ps, ns, uvs, tris = [], [], [], []
    for axis in range(3):
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[axis] = sign
            u = np.zeros(3)
            u[(axis + 1) % 3] = 1.0
            v = np.cross(n, u)  # (u, v, n) right-handed: counter-clockwise seen from outside
            corners = [(-1, -1), (1, -1), (1, 1), (-1, 1)]
            base = len(ps)
            for a, b in corners:
                ps.append(n + a * u + b * v)
                ns.append(n)
                uvs.append(((a + 1) / 2.0, (b + 1) / 2.0))
            tris += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    return np.array(ps), np.array(ns), np.array(uvs), np.array(tris)


def _sphere(n_lon: int = SPHERE_SEGMENTS[0], n_lat: int = SPHERE_SEGMENTS[1]):
    theta = np.linspace(0.0, math.pi, n_lat + 1)
    phi = np.linspace(0.0, 2.0 * math.pi, n_lon + 1)
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    p = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1).reshape(-1, 3)
    p[np.abs(p) < 1e-15] = 0.0
    uv = np.stack([ph / (2.0 * math.pi), th / math.pi], axis=-1).reshape(-1, 2)
    idx = np.arange((n_lat + 1) * (n_lon + 1)).reshape(n_lat + 1, n_lon + 1)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    t1 = np.stack([a, b, c], axis=-1)[:-1].reshape(-1, 3)  # the south-pole row of (a, b, c) is degenerate
    t2 = np.stack([a, c, d], axis=-1)[1:].reshape(-1, 3)  # the north-pole row of (a, c, d) is degenerate
    return p, p.copy(), uv, np.concatenate([t1, t2])


def _disk(n: int = DISK_SEGMENTS):
    phi = np.linspace(0.0, 2.0 * math.pi, n + 1)
    rim = np.stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)], axis=1)
    centre = np.zeros((n, 3))
    p = np.concatenate([centre, rim])
    uv = np.concatenate([np.stack([np.zeros(n), (phi[:-1] + phi[1:]) / (4.0 * math.pi)], axis=1),
                         np.stack([np.ones(n + 1), phi / (2.0 * math.pi)], axis=1)])
    j = np.arange(n)
    tri = np.stack([j, n + j, n + j + 1], axis=1)
    return p, np.tile([0.0, 0.0, 1.0], (p.shape[0], 1)), uv, tri


# ---------------------------------------------------------------------------------------------------------------


def _version(text: Optional[str], path: Path) -> tuple:
    if text is None:
        raise ValueError(f"Mitsuba scene {str(path)!r}: the <scene> element has no version attribute (versions "
                         f"0.5 to 3 are read)")
    try:
        parts = tuple(int(x) for x in text.strip().split("."))
    except ValueError:
        parts = ()
    if not parts or len(parts) > 3:
        raise ValueError(f"Mitsuba scene {str(path)!r}: version {text!r} is not a version number like '3.0.0'")
    parts = parts + (0,) * (3 - len(parts))
    if not ((parts[0] == 0 and parts[1] >= 5) or parts[0] in (2, 3)):
        raise ValueError(f"Mitsuba scene {str(path)!r}: version {text!r} is not one this reader knows (0.5.x, "
                         f"0.6.x, 2.x, 3.x)")
    return parts


def _parse(path: Path, depth: int = 0) -> ET.Element:
    try:
        data = path.read_bytes()
    except OSError as e:
        raise ValueError(f"Mitsuba scene {str(path)!r} could not be read: {e.strerror or e}") from None
    try:
        root = ET.fromstring(data)
    except ET.ParseError as e:
        raise ValueError(f"Mitsuba scene {str(path)!r}: malformed XML ({e})") from None
    if root.tag != "scene":
        raise ValueError(f"Mitsuba scene {str(path)!r}: the root element must be <scene>, got <{root.tag}>")
    # includes: the included file's children take the <include> element's place
    out = []
    for c in list(root):
        if c.tag == "include":
            fn = c.get("filename")
            if fn is None:
                raise ValueError(f"Mitsuba scene {str(path)!r}: an <include> has no filename")
            inc = path.parent / fn.replace("\\", "/")
            if not inc.is_file():
                raise ValueError(f"Mitsuba scene {str(path)!r}: <include filename={fn!r}> refers to a file that "
                                 f"does not exist (looked for {inc})")
            if depth >= 16:
                raise ValueError(f"Mitsuba scene {str(path)!r}: includes nest more than 16 deep")
            out.extend(list(_parse(inc, depth + 1)))
        else:
            out.append(c)
    root[:] = out
    return root


def _substitute(root: ET.Element, params: dict, path: Path) -> None:
    """Replace ``$name`` in every attribute from the ``<default>`` values, ``params`` overriding them."""
    values = {}
    for d in root.iter("default"):
        n, v = d.get("name"), d.get("value")
        if n is None or v is None:
            raise ValueError(f"Mitsuba scene {str(path)!r}: a <default> needs a name and a value, got {d.attrib}")
        values[n] = v
    values.update({str(k): str(v) for k, v in params.items()})

    def sub(m):
        if m.group(1) not in values:
            raise ValueError(f"Mitsuba scene {str(path)!r}: ${m.group(1)} has no value (give it a <default> or "
                             f"pass it in params; known: {sorted(values)})")
        return values[m.group(1)]

    for el in root.iter():
        for k, v in el.attrib.items():
            if "$" in v:
                el.set(k, _SUBST.sub(sub, v))


def read_mitsuba(path, *, params: Optional[dict] = None) -> SceneData:
    """Read a Mitsuba scene file (see the module docstring for what is read and how it maps).

    Args:
        path: the ``.xml`` file; the files it names are found relative to its folder.
        params: values for its ``$name`` parameters, overriding the file's ``<default>`` elements.

    Raises:
        ValueError: a missing or unreadable file, malformed XML, an unknown version, a parameter without a
            value, a ``ref`` to an unknown id, a missing referenced file, a malformed value; the message names
            the file and the element.
    """
    if not isinstance(path, (str, Path)):
        raise ValueError(f"path must be a str or Path, got {show(path)}")
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"Mitsuba scene {str(path)!r} " + ("is not a file" if path.exists() else "does not exist"))
    if params is not None and not isinstance(params, dict):
        raise ValueError(f"params must be None or a dict of parameter name -> value, got {show(params)}")
    root = _parse(path)
    version = _version(root.get("version"), path)
    _substitute(root, params or {}, path)
    rd = _Reader(path, version)
    for el in root.iter():
        if el.get("id") is not None and el.tag != "ref":
            rd.ids[el.get("id")] = el

    parts = []  # (name, kind, positions, normals, uvs, triangles, material index)
    lights, cameras, env, film = [], [], None, None
    for el in root:
        tag = el.tag
        if tag == "shape":
            shape = _shape(rd, el)
            if shape is not None:
                parts.append(shape)
        elif tag == "emitter":
            got = _emitter(rd, el)
            if isinstance(got, LightData):
                lights.append(got)
            elif isinstance(got, EnvironmentData):
                if env is None:
                    env = got
                else:
                    rd.note("more than one environment emitter (the first is kept)")
        elif tag == "sensor":
            cam, size = _sensor(rd, el, len(cameras))
            if cam is not None:
                cameras.append(cam)
                if film is None:
                    film = size
        elif tag in ("bsdf", "texture", "default", "ref", "spectrum", "rgb", "float"):
            pass  # read where they are used
        elif tag in _SILENT_TOP:
            pass
        else:
            rd.note(f"<{tag}> elements")

    return _assemble(rd, parts, lights, cameras, env, film)


def _shape(rd: _Reader, el: ET.Element):
    kind = el.get("type")
    inward = False  # a negative sphere radius turns its normals inward (Mitsuba 3's sphere does the same)
    p = rd.params(el)
    name = el.get("id") or el.get("name") or kind or "shape"
    m = rd.transform_of(p.get("to_world"))
    used = {"to_world", "filename", "face_normals", "flip_normals", "flip_tex_coords", "center", "radius"}
    if kind in ("obj", "ply"):
        fn = rd.string_of(p.get("filename"), None)
        if fn is None:
            rd.fail(f"{rd.label(el)} has no filename")
        f = rd.file(el, fn)
        flip_v = rd.bool_of(p.get("flip_tex_coords"), True)
        key = (f.resolve(), kind, flip_v)
        if key not in rd.mesh_cache:
            rd.mesh_cache[key] = _load_mesh(rd, f, kind, flip_v)
        pos, nrm, uv, tri = rd.mesh_cache[key]
        name = el.get("id") or f.stem
    elif kind == "rectangle":
        pos, nrm, uv, tri = _rectangle()
    elif kind == "cube":
        pos, nrm, uv, tri = _cube()
    elif kind == "disk":
        pos, nrm, uv, tri = _disk()
    elif kind == "sphere":
        pos, nrm, uv, tri = _sphere()
        c = rd.vec3_of(p["center"]) if "center" in p else np.zeros(3)
        r = rd.float_of(p.get("radius"), 1.0)
        inward, r = r < 0.0, abs(r)
        local = np.eye(4)
        local[:3, :3] *= r
        local[:3, 3] = c
        m = m @ local
    else:
        rd.note(f"shape type {kind!r}")
        return None
    if pos.shape[0] == 0 or tri.shape[0] == 0:
        rd.note(f"{rd.label(el)} without triangles")
        return None
    for k in sorted(set(p) - used):
        if rd.resolve(p[k]).tag not in ("bsdf", "emitter"):
            rd.note(f"{kind} shape parameter {k!r}")
    if abs(float(np.linalg.det(m[:3, :3]))) < 1e-300:
        rd.note(f"{rd.label(el)} with a singular to_world (flattened)")
    pos, nrm, tri = transform_mesh(pos, nrm, tri, m)
    if rd.bool_of(p.get("flip_normals"), False) != inward:
        nrm, tri = -nrm, tri[:, [0, 2, 1]]
    if rd.bool_of(p.get("face_normals"), False):
        tri, pos, uv = split_flat(tri, pos, uv)
        nrm = np.repeat(face_normals(pos, tri), 3, axis=0)
    bsdfs = rd.children(el, "bsdf")
    if len(bsdfs) > 1:
        rd.note(f"{rd.label(el)} with more than one BSDF (the first is used)")
    mat = rd.material(bsdfs[0] if bsdfs else None)
    for e in rd.children(el, "emitter"):
        if e.get("type") != "area":
            rd.note(f"emitter type {e.get('type')!r} inside a shape")
            continue
        ep = rd.params(e)
        if "radiance" in ep and rd.resolve(ep["radiance"]).tag == "texture":
            rd.note("a textured area emitter radiance (radiance 1 is used)")
        radiance = rd.color_of(ep.get("radiance"), (1.0, 1.0, 1.0))
        if any(c < 0 or not math.isfinite(c) for c in radiance):
            rd.fail(f"{rd.label(e)}: radiance must be finite and >= 0, got {radiance}")
        base = rd.materials[mat]
        rd.materials.append(emission_material(base, radiance, name=f"{base.name}+{name}"))
        mat = len(rd.materials) - 1
        break
    if el.find("medium") is not None:
        rd.note("media")
    return name, kind, pos, nrm, uv, tri, mat


def _load_mesh(rd: _Reader, f: Path, kind: str, flip_v: bool):
    if kind == "obj":
        from .obj import parse_obj

        mesh = parse_obj(f, flip_v=flip_v)
        for w in mesh.warnings:
            rd.note(w)
        uv = mesh.uvs if mesh.uvs is not None else np.zeros((mesh.positions.shape[0], 2))
        return mesh.positions, mesh.normals, uv, mesh.triangles
    from ..meshio import read_ply

    d = read_ply(f)
    pos, tri = d["vertices"], d["faces"]
    nrm = d["normals"] if d["normals"] is not None else compute_normals(pos, tri)
    return pos, nrm, np.zeros((pos.shape[0], 2)), tri


def _emitter(rd: _Reader, el: ET.Element):
    kind = el.get("type")
    p = rd.params(el)
    name = el.get("id") or kind or "emitter"
    m = rd.transform_of(p.get("to_world"))
    used = {"to_world", "sampling_weight"}

    def get(k):
        used.add(k)
        return p.get(k)

    def rgb_power(key):
        c = np.array(rd.color_of(get(key), (1.0, 1.0, 1.0)), dtype=np.float64)
        if not np.isfinite(c).all() or (c < 0).any():
            rd.fail(f"{rd.label(el)}: {key} must be finite and >= 0, got {tuple(c)}")
        s = float(c.max())
        return (tuple(c / s) if s > 0 else (1.0, 1.0, 1.0)), s

    out = None
    if kind == "point":
        pos = rd.vec3_of(get("position")) if "position" in p else m[:3, 3]
        col, s = rgb_power("intensity")
        out = LightData(name=name, kind="point", color=col, intensity=s, position=tuple(pos))
    elif kind == "spot":
        col, s = rgb_power("intensity")
        cutoff = rd.float_of(get("cutoff_angle"), 20.0)
        beam = rd.float_of(get("beam_width"), cutoff * 0.75)
        cutoff = min(max(cutoff, 1e-6), 180.0)
        beam = min(max(beam, 0.0), cutoff)
        d = m[:3, 2]
        out = LightData(name=name, kind="spot", color=col, intensity=s, position=tuple(m[:3, 3]),
                        direction=tuple(d), inner_cone_rad=math.radians(beam), outer_cone_rad=math.radians(cutoff),
                        spot_falloff="linear_angle")
        if "texture" in p:
            rd.note("spot light textures")
            used.add("texture")
    elif kind == "directional":
        d = rd.vec3_of(get("direction")) if "direction" in p else m[:3, 2]
        if "direction" in p and "to_world" in p:
            d = m[:3, :3] @ d
        col, s = rgb_power("irradiance")
        out = LightData(name=name, kind="directional", color=col, intensity=s, direction=tuple(d))
    elif kind == "envmap":
        fn = rd.string_of(get("filename"), None)
        if fn is None:
            rd.fail(f"{rd.label(el)} has no filename")
        f = rd.file(el, fn)
        scale = rd.float_of(get("scale"), 1.0)
        if not (math.isfinite(scale) and scale >= 0):
            rd.fail(f"{rd.label(el)}: scale must be finite and >= 0, got {scale}")
        used.update(("gamma", "filter_type", "cache"))
        out = EnvironmentData(image=f, scale=scale, to_world=_rotation_part(m), name=name)
    elif kind == "constant":
        col, s = rgb_power("radiance")
        out = EnvironmentData(image=np.array(col, dtype=np.float32).reshape(1, 1, 3) * np.float32(s),
                              name=name)
    elif kind == "area":
        rd.note("area emitters outside a shape")
        return None
    else:
        rd.note(f"emitter type {kind!r}")
        return None
    for k in sorted(set(p) - used):
        rd.note(f"{kind} emitter parameter {k!r}")
    return out


def _rotation_part(m: np.ndarray) -> np.ndarray:
    """The rotation of a 4x4 matrix's linear part (polar decomposition; the identity for a singular one)."""
    u, s, vt = np.linalg.svd(m[:3, :3])
    if not s.min() > 1e-12:
        return np.eye(3)
    r = u @ vt
    if np.linalg.det(r) < 0:
        u[:, -1] *= -1.0
        r = u @ vt
    return r


def _sensor(rd: _Reader, el: ET.Element, index: int):
    kind = el.get("type")
    if kind not in ("perspective", "thinlens"):
        rd.note(f"sensor type {kind!r}")
        return None, None
    if kind == "thinlens":
        rd.note("thinlens sensors (shown as pinhole cameras: no depth of field)")
    p = rd.params(el)
    m = rd.transform_of(p.get("to_world"))
    width, height = 768, 576
    films = [c for c in el if c.tag == "film"]
    if films:
        fp = rd.params(films[0])
        width = int(round(rd.float_of(fp.get("width"), 768)))
        height = int(round(rd.float_of(fp.get("height"), 576)))
        if width < 1 or height < 1:
            rd.fail(f"{rd.label(films[0])}: width and height must be >= 1, got {width} x {height}")
        if any(k in fp for k in ("crop_width", "crop_height", "crop_offset_x", "crop_offset_y")):
            rd.note("film crop windows")
    aspect = width / height
    axis = (rd.string_of(p.get("fov_axis"), "x") or "x").lower()
    if axis not in ("x", "y", "diagonal", "smaller", "larger"):
        rd.fail(f"{rd.label(el)}: fov_axis must be one of ['x', 'y', 'diagonal', 'smaller', 'larger'], got {axis!r}")
    if "fov" in p:
        fov = rd.float_of(p["fov"], 45.0)
        if not 0.0 < fov < 180.0:
            rd.fail(f"{rd.label(el)}: fov must be in (0, 180) degrees, got {fov}")
    else:
        fl = (rd.string_of(p.get("focal_length"), "50mm") or "50mm").strip().lower()
        try:
            f_mm = float(fl[:-2] if fl.endswith("mm") else fl)
        except ValueError:
            rd.fail(f"{rd.label(el)}: focal_length must be a length like '50mm', got {fl!r}")
        if not f_mm > 0:
            rd.fail(f"{rd.label(el)}: focal_length must be > 0, got {fl!r}")
        fov, axis = math.degrees(2.0 * math.atan(36.0 / (2.0 * f_mm))), "x"
    fy = fov_y_deg(fov, axis, aspect)
    eye = m[:3, 3]
    fwd, up_raw, left = m[:3, 2], m[:3, 1], m[:3, 0]
    nf = float(np.linalg.norm(fwd))
    if not nf > 0:
        rd.fail(f"{rd.label(el)}: to_world maps the view direction to zero")
    fwd = fwd / nf
    up = up_raw - fwd * float(up_raw @ fwd)
    if not np.linalg.norm(up) > 1e-12:
        rd.fail(f"{rd.label(el)}: to_world's up is parallel to its view direction")
    up = up / np.linalg.norm(up)
    if float(np.cross(fwd, up) @ -left) < 0:
        rd.note("a mirroring sensor to_world (the image is shown unmirrored)")
    znear = rd.float_of(p.get("near_clip"), 1e-2)
    zfar = rd.float_of(p.get("far_clip"), 1e4)
    cam = CameraData(name=el.get("id") or f"sensor{index}", kind="perspective", eye=tuple(eye), forward=tuple(fwd),
                     up=tuple(up), yfov_rad=math.radians(fy), aspect=aspect, znear=max(znear, 0.0),
                     zfar=zfar if zfar > znear else None)
    for k in sorted(set(p) - {"to_world", "fov", "fov_axis", "focal_length", "near_clip", "far_clip",
                              "aperture_radius", "focus_distance", "shutter_open", "shutter_close",
                              "principal_point_offset_x", "principal_point_offset_y"}):
        if rd.resolve(p[k]).tag not in ("film", "sampler"):
            rd.note(f"{kind} sensor parameter {k!r}")
    return cam, (width, height)


def _assemble(rd: _Reader, parts, lights, cameras, env, film) -> SceneData:
    vert, nrm, uvs, tri, mat, shapes = [], [], [], [], [], []
    nv = nt = 0
    for name, kind, p, n, uv, t, m in parts:
        shapes.append(ShapeData(name=name, kind=kind, vertex_range=(nv, nv + p.shape[0]),
                                triangle_range=(nt, nt + t.shape[0]), material=int(m)))
        vert.append(p)
        nrm.append(n)
        uvs.append(uv)
        tri.append(t + nv)
        mat.append(np.full(t.shape[0], m, dtype=np.int32))
        nv += p.shape[0]
        nt += t.shape[0]
    if nv > np.iinfo(np.int32).max:
        rd.fail(f"the scene has {nv} vertices, more than int32 indices can address")
    if parts:
        pos, nn = np.concatenate(vert), np.concatenate(nrm)
        uv, tr = np.concatenate(uvs), np.concatenate(tri)
        tan = complete_tangents(pos, nn, uv, tr)
        mids = np.concatenate(mat)
    else:
        pos, nn, uv = np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 2))
        tr, tan, mids = np.zeros((0, 3), np.int64), np.zeros((0, 4)), np.zeros(0, np.int32)
    # keep only the materials some triangle uses, in first-use order
    used = np.unique(mids) if mids.size else np.zeros(0, np.int64)
    remap = np.full(max(len(rd.materials), 1), -1, dtype=np.int32)
    remap[used] = np.arange(used.shape[0], dtype=np.int32)
    materials = [rd.materials[i] for i in used]
    mids = remap[mids] if mids.size else mids
    shapes = [replace(s, material=int(remap[s.material])) for s in shapes]
    notes = [msg if n == 1 else f"{msg} (x{n})" for msg, n in rd.notes.items()]
    if notes:
        warnings.warn(f"Mitsuba scene {str(rd.path)!r}: left out or approximated: " + "; ".join(notes),
                      stacklevel=3)
    return SceneData(
        path=rd.path,
        vertices=pos.astype(np.float32),
        normals=nn.astype(np.float32),
        tangents=tan.astype(np.float32),
        uvs=uv.astype(np.float32),
        uvs1=None,
        colors=None,
        triangles=tr.astype(np.int32),
        material_ids=mids.astype(np.int32),
        materials=materials,
        images=rd.images,
        lights=lights,
        cameras=cameras,
        camera=cameras[0] if cameras else None,
        environment=env,
        film_size=film,
        warnings=tuple(notes),
        shapes=shapes,
    )
