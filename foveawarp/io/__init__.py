"""Scene file readers, one module per format, each returning a :class:`SceneData`:
:func:`read_gltf` (glTF 2.0), and the image decoders of :mod:`foveawarp.io.images`."""

from .gltf import GltfCamera, GltfLight, GltfScene, read_gltf
from .scenedata import CameraData, EnvironmentData, LightData, SceneData, ShapeData, emission_material

__all__ = [
    "SceneData",
    "LightData",
    "CameraData",
    "EnvironmentData",
    "ShapeData",
    "emission_material",
    "read_gltf",
    "GltfScene",
    "GltfLight",
    "GltfCamera",
]
