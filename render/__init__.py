"""Offscreen hair rasteriser: polylines and meshes in, images and videos out. No physics.

Numpy arrays in, `(H, W, 3) uint8` sRGB images out. Rendering runs in Taichi kernels on
whatever arch Taichi was initialised with; if nobody initialised it, the first render calls
`render.init()` (CPU). See render/README.md.
"""

from .backdrop import Backdrop
from .camera import Camera, fit_camera
from .fibre import HairMaterial
from .fibre_lobes import fibre_scattering
from .frame import RenderSettings, hair_shadow, render_buffers, render_frame
from .geometry import Hair, Mesh, capsule_mesh
from .runtime import init
from .shading import (AmbientLight, DirectionalLight, HairShading, Light, Lighting, kajiya_kay,
                      three_point_lights)
from .shadows import ShadowSettings
from .video import ProgressBar, Turntable, read_png, turntable, write_mp4, write_png

__all__ = [
    "AmbientLight", "Backdrop", "Camera", "DirectionalLight", "Hair", "HairMaterial", "HairShading", "Light",
    "Lighting", "Mesh", "ProgressBar", "RenderSettings", "ShadowSettings", "Turntable",
    "capsule_mesh", "fibre_scattering", "fit_camera", "hair_shadow", "init", "kajiya_kay",
    "read_png", "render_buffers", "render_frame", "three_point_lights", "turntable", "write_mp4",
    "write_png",
]
