"""Offscreen hair rasteriser: polylines and meshes in, images and videos out. No physics.

Numpy arrays in, `(H, W, 3) uint8` sRGB images out. Rendering runs in Taichi kernels on
whatever arch Taichi was initialised with; if nobody initialised it, the first render calls
`render.init()` (CPU). See render/README.md.
"""

from .camera import Camera
from .frame import RenderSettings, hair_shadow, render_buffers, render_frame
from .geometry import Hair, Mesh
from .runtime import init
from .shading import HairShading, Light, Lighting, kajiya_kay
from .shadows import ShadowSettings
from .video import ProgressBar, Turntable, read_png, turntable, write_mp4, write_png

__all__ = [
    "Camera", "Hair", "HairShading", "Light", "Lighting", "Mesh", "ProgressBar",
    "RenderSettings", "ShadowSettings", "Turntable", "hair_shadow", "init", "kajiya_kay",
    "read_png", "render_buffers", "render_frame", "turntable", "write_mp4", "write_png",
]
