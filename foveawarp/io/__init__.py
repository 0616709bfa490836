"""Scene file readers, one module per format, each returning a :class:`SceneData`:
:func:`read_gltf` (glTF 2.0), :func:`read_obj` (OBJ + MTL), :func:`read_mitsuba` (Mitsuba XML, versions 0.5 to 3),
and the image decoders of :mod:`foveawarp.io.images`."""

from .gltf import GltfCamera, GltfLight, GltfScene, read_gltf
from .mitsuba import read_mitsuba
from .obj import read_obj
from .scenedata import CameraData, EnvironmentData, LightData, SceneData, ShapeData, emission_material

__all__ = [
    "SceneData",
    "LightData",
    "CameraData",
    "EnvironmentData",
    "ShapeData",
    "emission_material",
    "read_gltf",
    "read_obj",
    "read_mitsuba",
    "GltfScene",
    "GltfLight",
    "GltfCamera",
]
