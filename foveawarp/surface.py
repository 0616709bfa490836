"""The device description of a textured scene's surfaces and environment, for the textured G-buffer and shading.

:func:`surface_data` fills a :class:`foveawarp.kernels.surface.SurfaceData` from a ``DeviceScene`` whose scene has
materials (``Scene.is_textured``), once per (scene, texture LOD mode); :func:`environment_map` gives the
``EnvironmentMap`` struct of the scene's environment (or a black 1 x 1 map and ``False``). Scenes without
materials never reach these: their stages keep the untextured kernels.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .config import check_choice
from .kernels import surface as sk
from .kernels import texture as tk
from .textures import TEXTURE_LOD_MODES

__all__ = ["is_textured", "surface_data", "environment_map", "set_material_specular"]

_LOD = {"none": int(tk.LOD_NONE), "ray_cone": int(tk.LOD_RAY_CONE)}


def is_textured(dscene) -> bool:
    """Whether the stages shade ``dscene`` with the textured kernels (its scene has materials)."""
    return getattr(dscene, "mat_base_color", None) is not None


def _cache(dscene) -> dict:
    c = getattr(dscene, "_surface_cache", None)
    if c is None:
        c = {}
        dscene._surface_cache = c
    return c


def _specular_array(dscene) -> wp.array:
    """(M,) float32 dielectric Fresnel scale per material, 1 (glTF's core material), shared by every LOD mode."""
    c = _cache(dscene)
    if "specular" not in c:
        c["specular"] = wp.array(np.ones(max(dscene.num_materials, 1), dtype=np.float32), dtype=float,
                                 device=dscene.device)
    return c["specular"]


def set_material_specular(dscene, specular) -> None:
    """Set the dielectric Fresnel scale of every material (``KHR_materials_specular``'s ``specularFactor``, in
    [0, 1]; 0 leaves a dielectric's pure Lambert lobe): one number or one per material. A setting of the
    scene on its device, read by kernels launched after it."""
    if not is_textured(dscene):
        raise ValueError("set_material_specular needs a scene with materials (Scene.materials), got an untextured one")
    s = np.broadcast_to(np.asarray(specular, dtype=np.float64), (dscene.num_materials,))
    if not (np.all(np.isfinite(s)) and s.min() >= 0.0 and s.max() <= 1.0):
        raise ValueError(f"specular must be in [0, 1] (one value or {dscene.num_materials}), got {specular!r}")
    _specular_array(dscene).assign(s.astype(np.float32))


def surface_data(dscene, texture_lod: str = "ray_cone") -> sk.SurfaceData:
    """The :class:`SurfaceData` of a textured ``dscene`` with ``texture_lod`` ("ray_cone" or "none"), built once
    per mode (it refers to the scene's device arrays: moving vertices are seen)."""
    check_choice("ShadingConfig.texture_lod", texture_lod, TEXTURE_LOD_MODES)
    if not is_textured(dscene):
        raise ValueError("surface_data needs a scene with materials (Scene.materials), got an untextured one")
    c = _cache(dscene)
    key = ("surface", texture_lod)
    if key in c:
        return c[key]
    dev = dscene.device
    one_uv = wp.zeros(1, dtype=wp.vec2, device=dev)
    s = sk.SurfaceData()
    s.indices = dscene.indices
    s.points = dscene.points
    s.vnormals = dscene.vertex_normals
    s.smooth = dscene.face_smooth
    s.uvs = dscene.uvs if dscene.uvs is not None else one_uv
    s.uvs1 = dscene.uvs1 if dscene.uvs1 is not None else s.uvs
    s.has_tangents = 0 if dscene.tangents is None else 1
    s.tangents = dscene.tangents if dscene.tangents is not None else wp.zeros(1, dtype=wp.vec4, device=dev)
    s.face_material = dscene.face_material
    s.base_color = dscene.mat_base_color
    s.metallic = dscene.mat_metallic
    s.roughness = dscene.mat_roughness
    s.normal_scale = dscene.mat_normal_scale
    s.occlusion_strength = dscene.mat_occlusion_strength
    s.alpha_cutoff = dscene.mat_alpha_cutoff
    s.specular = _specular_array(dscene)
    s.emission = dscene.mat_emission
    s.transmission = dscene.mat_transmission
    s.ior = dscene.mat_ior
    s.alpha_mode = dscene.mat_alpha_mode
    s.double_sided = dscene.mat_double_sided
    s.texture = dscene.mat_texture
    s.tex_texcoord = dscene.tex_texcoord
    s.tex_uv_linear = dscene.tex_uv_linear
    s.tex_uv_offset = dscene.tex_uv_offset
    s.atlas = dscene.textures.atlas
    s.lod_mode = _LOD[texture_lod]
    modes = dscene.scene.materials.alpha_mode
    s.has_cutouts = int(bool(np.any(modes != 0)))
    s.ray_eps = float(dscene.ray_eps)
    c[key] = s
    return s


def environment_map(dscene) -> tuple:
    """(``EnvironmentMap`` struct, has_environment) of ``dscene``'s scene: its ``Scene.environment`` (an array,
    an .hdr/.exr path or a ``foveawarp.envmap.Environment``) on the device, or a black 1 x 1 map and False."""
    from .envmap import Environment

    c = _cache(dscene)
    if "env" in c:
        return c["env"]
    env = Environment.of(dscene.scene.environment)
    has = env is not None
    if env is None:
        env = Environment(np.zeros((1, 1, 3), dtype=np.float32), name="black")
    if has and env.is_black:
        has = False
    c["env"] = (env.to_device(dscene.device), has)
    return c["env"]
