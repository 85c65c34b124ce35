"""A backdrop: a matte wall behind the subject, lit by the frame's lights and shadowed by the hair
and meshes through the same light maps as the meshes, so the figure casts its shadow on it.

Where no mesh is seen, the camera ray through the pixel's centre meets the wall's plane; that
point is shaded Lambert (no highlight) with its key light shadow from `shadows` and added to the
pixel weighted by the fraction of the pixel the meshes leave uncovered (the fraction
`shading.shade_mesh` gives the background). One kernel call per directional light, adding up,
as the meshes' shading does.
"""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from .bundles import MeshPixelArgs, ShadowMapArgs
from .camera import Camera, f32, mat4f, unit, vec3f, vec4f
from .colour import srgb_colour, srgb_to_linear
from .raster import EDGE_SAMPLES, empty_key, sub_pixel_edge
from .shading import shade_surface
from .shadows import filtered_transmittance
from .threads import spread_rows


def _vec3(name: str, value) -> np.ndarray:
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be 3 finite numbers, got {value!r}")
    return v


@dataclass(frozen=True, kw_only=True)
class Backdrop:
    """A flat matte wall, infinite, lit and shadowed like the meshes. point [m]: a point on it;
    normal: its direction towards the subject and camera (non-zero, normalised here); colour:
    its albedo, sRGB in [0, 1]. Pixels whose camera ray misses it (looking away from it) show
    the wall unshadowed."""

    point: tuple
    normal: tuple
    colour: tuple = (0.25, 0.25, 0.27)

    def __post_init__(self):
        object.__setattr__(self, "point", tuple(_vec3("point", self.point)))
        n = _vec3("normal", self.normal)
        if np.linalg.norm(n) < 1e-9:
            raise ValueError(f"normal must be a non-zero 3-vector, got {self.normal!r}")
        object.__setattr__(self, "normal", tuple(n / np.linalg.norm(n)))
        object.__setattr__(self, "colour", tuple(srgb_colour("colour", self.colour)))

    def plane(self) -> np.ndarray:
        """(nx, ny, nz, d) float32 with n . x + d = 0 on the wall."""
        n = np.asarray(self.normal)
        return np.array([*n, -float(n @ np.asarray(self.point))], dtype=np.float32)

    def albedo(self) -> np.ndarray:
        """Linear RGB albedo, (3,) float32."""
        return srgb_to_linear(self.colour).astype(np.float32)


def camera_to_world(camera: Camera) -> np.ndarray:
    """The inverse of the camera's view matrix, (4, 4) float32: camera space to world."""
    view, _ = camera.matrices()
    return np.linalg.inv(view.astype(np.float64)).astype(np.float32)


@ti.func
def background_fraction(pixels: ti.template(), px: ti.i32, py: ti.i32) -> f32:
    """Fraction in [0, 1] of pixel (px, py) that shows the background, as `shade_mesh` weighs
    it: at a mesh edge (sub-pixels disagree) the sub-pixels that hit no mesh, elsewhere 1 where
    no mesh covers the centre and 0 where one does."""
    mesh_key, edge_index = ti.static(pixels.pixel_key, pixels.pixel_edge_index)
    edge, n_mesh = sub_pixel_edge(pixels, edge_index[py, px])
    result = ti.select(mesh_key[py, px] == empty_key(), f32(1.0), f32(0.0))
    if edge == 1:
        full = EDGE_SAMPLES * EDGE_SAMPLES
        result = ti.cast(full - n_mesh, f32) / f32(full)
    return result


@ti.kernel
def shade_backdrop(pixels: MeshPixelArgs, cam_to_world: mat4f, proj: vec4f, plane: vec4f,
                   albedo: vec3f, to_light: vec3f, light: vec3f, ambient: vec3f, sview: mat4f,
                   sproj: vec4f, sm: ShadowMapArgs, sparams: vec4f):
    """base (H, W) += the wall's linear radiance under one light (irradiance / pi `light`,
    shadowed by its map sview, sproj, sm, sparams) plus `ambient` (zero after the first light)
    times the pixel's background fraction. cam_to_world, proj: the camera (`camera_to_world`,
    `Camera.matrices` at the frame's scale); plane: the wall (`Backdrop.plane`); albedo:
    linear. One thread per pixel (CPU: per row)."""
    origin = cam_to_world @ vec4f(0.0, 0.0, 0.0, 1.0)
    eye = vec3f(origin[0], origin[1], origin[2])
    spread_rows(pixels.pixel_base.shape[0], pixels.pixel_base.shape[1], shade_backdrop_pixel,
                (pixels, cam_to_world, eye, proj, plane, albedo, to_light, light, ambient, sview, sproj,
                 sm, sparams))


@ti.func
def shade_backdrop_pixel(pixels: ti.template(), cam_to_world: mat4f, eye: vec3f, proj: vec4f,
                         plane: vec4f, albedo: vec3f, to_light: vec3f, light: vec3f, ambient: vec3f,
                         sview: mat4f, sproj: vec4f, sm: ti.template(), sparams: vec4f,
                         py: ti.i32, px: ti.i32):
    """`shade_backdrop` for pixel (px, py); eye [m]: the camera's position."""
    base = ti.static(pixels.pixel_base)
    n = vec3f(plane[0], plane[1], plane[2])
    frac = background_fraction(pixels, px, py)
    if frac > 0.0:
        cam = vec4f((ti.cast(px, f32) + f32(0.5) - proj[1]) / proj[0],
                    -(ti.cast(py, f32) + f32(0.5) - proj[2]) / proj[0], f32(-1.0), f32(0.0))
        w = cam_to_world @ cam
        d = unit(vec3f(w[0], w[1], w[2]))
        facing = n.dot(d)
        shadow = f32(1.0)
        if facing < 0.0:   # the ray meets the wall's front in front of the eye
            t = -(n.dot(eye) + plane[3]) / facing
            if t > 0.0:
                p = eye + t * d
                # off the wall by two shadow texels, as the meshes, against self-shadowing
                shadow = filtered_transmittance(p + n * (f32(2.0) * sparams[3]), sview,
                                                sproj, sm, sparams)
        c = shade_surface(n, to_light, -d, albedo, light, ambient, shadow, f32(0.0),
                          f32(1.0))
        base[py, px] = base[py, px] + frac * c   # one thread per pixel: no atomic add
