"""foveawarp: gaze-contingent (foveated) real-time ray tracing with NVIDIA Warp kernels, on CUDA and CPU."""

from . import ops, parallel, scenes  # importing scenes registers the built-in scenes with load_scene
from .buffers import Frame, GBuffer
from .camera import Camera
from .config import (
    Config,
    DofConfig,
    FoveationConfig,
    IndirectConfig,
    ReconstructionConfig,
    ReorderConfig,
    SaliencyConfig,
    ShadingConfig,
    TemporalConfig,
)
from .frame_loop import FrameLoop
from .scene import AreaLight, DeviceScene, Light, Scene, load_scene

__version__ = "0.1.0"

__all__ = [
    "AreaLight",
    "Camera",
    "Config",
    "DeviceScene",
    "DofConfig",
    "FoveationConfig",
    "Frame",
    "FrameLoop",
    "GBuffer",
    "IndirectConfig",
    "Light",
    "ReconstructionConfig",
    "ReorderConfig",
    "SaliencyConfig",
    "Scene",
    "ShadingConfig",
    "TemporalConfig",
    "load_scene",
    "ops",
]
