"""Lights and shading models: Kajiya-Kay hair with two shifted lobes, Lambert + Blinn skin.

All radiometric quantities are linear RGB. Hair is shaded per vertex (tangent from the
neighbouring vertices) and interpolated along segments; meshes are shaded per pixel in
`shade_mesh` below.

Kajiya-Kay with shifted lobes (Scheuermann 2004, after Marschner et al. 2003): with T the unit
tangent, L the direction to the light, V to the eye and H = (L + V)/|L + V|, the longitudinal
half angle is theta_h = asin(T.H). A lobe with shift s and exponent p is cos(theta_h - s)^p;
for s = 0 it is sin(T, H)^p, the Kajiya-Kay highlight, largest where T is perpendicular to H.
The primary lobe (R, surface reflection) is white; the secondary (TRT, light that entered the
fibre) is tinted by the hair colour and shifted the other way.
"""

import math
from dataclasses import dataclass

import numpy as np
import taichi as ti

from .bundles import HairArgs, MeshArgs, MeshPixelArgs, ShadowMapArgs
from .camera import f32, mat4f, unit, vec3f, vec4f
from .colour import srgb_colour, srgb_to_linear
from .raster import (EDGE_SAMPLES, barycentric, empty_key, key_prim, perspective_weights, pixel_centre,
                     sub_pixel_centre, sub_pixel_edge)
from .runtime import buffer, ensure_init, upload
from .shadows import filtered_transmittance
from .threads import spread_rows

vec8f = ti.types.vector(8, ti.f32)


def _rgb(name: str, value) -> np.ndarray:
    c = np.asarray(value, dtype=np.float64)
    if c.shape != (3,) or not np.all(np.isfinite(c) & (c >= 0.0)):
        raise ValueError(f"{name} must be 3 finite values >= 0 (linear RGB), got {value!r}")
    return c


@dataclass(frozen=True)
class DirectionalLight:
    """A distant light. direction: the direction the light travels, from the light into the
    scene (as Mitsuba's `directional` emitter; normalised here). irradiance_rgb: linear RGB
    irradiance [W/m^2] on a surface facing the light. shadows: occluded by hair and meshes."""

    direction: tuple = (-0.4, -0.7, -0.6)
    irradiance_rgb: tuple = (3.0, 3.0, 3.0)
    shadows: bool = True

    def __post_init__(self):
        d = np.asarray(self.direction, dtype=np.float64)
        if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) < 1e-9:
            raise ValueError(f"direction must be a non-zero 3-vector, got {self.direction!r}")
        object.__setattr__(self, "direction", tuple(d / np.linalg.norm(d)))
        object.__setattr__(self, "irradiance_rgb", tuple(_rgb("irradiance_rgb", self.irradiance_rgb)))

    @property
    def to_light(self) -> np.ndarray:
        """Unit vector from the scene towards the light, (3,) float32."""
        return -np.asarray(self.direction, dtype=np.float32)


@dataclass(frozen=True)
class AmbientLight:
    """Uniform environment light of linear RGB radiance `radiance_rgb` [W/(m^2 sr)] from every
    direction, unshadowed (Mitsuba's `constant` emitter without occlusion)."""

    radiance_rgb: tuple = (0.2, 0.21, 0.24)

    def __post_init__(self):
        object.__setattr__(self, "radiance_rgb", tuple(_rgb("radiance_rgb", self.radiance_rgb)))


def three_point_lights(view_direction=(0.0, 1.0, 0.25), up=(0.0, 0.0, 1.0),
                       irradiance: float = 6.0, ambient: float = 0.12) -> list:
    """Key, fill and rim lights for a camera looking along -view_direction (from the subject
    towards the eye) with `up`: the key (shadowed) 45 degrees to the camera's left and 35 up,
    the fill (half the key, unshadowed) 60 degrees to the right and level, the rim (0.8 of
    the key, shadowed) from behind and above; plus a cool ambient of `ambient` x irradiance / pi
    radiance. irradiance: the key's [W/m^2], warm white."""
    d = np.asarray(view_direction, float)
    d /= np.linalg.norm(d)
    u = np.asarray(up, float)
    right = np.cross(-d, u)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, -d)

    def towards(az, el):   # direction to the light: az from the camera towards the right
        a, e = np.radians(az), np.radians(el)
        return np.cos(e) * (np.cos(a) * d + np.sin(a) * right) + np.sin(e) * true_up

    warm, cool = np.array([1.0, 0.95, 0.88]), np.array([0.85, 0.9, 1.0])
    e = float(irradiance)
    return [DirectionalLight(tuple(-towards(-45, 35)), tuple(e * warm)),
            DirectionalLight(tuple(-towards(60, 0)), tuple(0.5 * e * cool), shadows=False),
            DirectionalLight(tuple(-towards(180, 40)), tuple(0.8 * e * warm)),
            AmbientLight(tuple(ambient * e / math.pi * cool))]


def split_lights(lights) -> tuple[list, np.ndarray]:
    """(directional lights, summed ambient radiance (3,) float32) of a list of lights."""
    if isinstance(lights, (DirectionalLight, AmbientLight)):
        lights = [lights]
    directional, ambient = [], np.zeros(3)
    for i, light in enumerate(lights):
        if isinstance(light, DirectionalLight):
            directional.append(light)
        elif isinstance(light, AmbientLight):
            ambient += light.radiance_rgb
        else:
            raise ValueError(f"lights[{i}] must be a render.DirectionalLight or AmbientLight, "
                             f"got {type(light).__name__}")
    return directional, ambient.astype(np.float32)


@dataclass(frozen=True, kw_only=True)
class Light:
    """Directional key light. to_light: direction from the scene towards the light (normalised
    here). colour: sRGB in [0, 1]. intensity >= 0: multiplies colour (linear)."""

    to_light: tuple = (0.4, 0.7, 0.6)
    colour: tuple = (1.0, 0.97, 0.92)
    intensity: float = 1.8

    def __post_init__(self):
        d = np.asarray(self.to_light, dtype=np.float64)
        if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) < 1e-9:
            raise ValueError(f"to_light must be a non-zero 3-vector, got {self.to_light!r}")
        object.__setattr__(self, "to_light", tuple(d / np.linalg.norm(d)))
        object.__setattr__(self, "colour", tuple(srgb_colour("colour", self.colour)))
        if not self.intensity >= 0.0:
            raise ValueError(f"intensity must be >= 0, got {self.intensity}")

    def radiance(self) -> np.ndarray:
        """Linear RGB irradiance of the light, (3,) float32."""
        return (srgb_to_linear(self.colour) * self.intensity).astype(np.float32)


@dataclass(frozen=True, kw_only=True)
class Lighting:
    """A shadowed key light plus unshadowed ambient light (sRGB colour times intensity)."""

    key: Light = Light()
    ambient: tuple = (0.75, 0.8, 1.0)
    ambient_intensity: float = 0.3

    def __post_init__(self):
        if not isinstance(self.key, Light):
            raise ValueError(f"key must be a render.Light, got {type(self.key).__name__}")
        object.__setattr__(self, "ambient", tuple(srgb_colour("ambient", self.ambient)))
        if not self.ambient_intensity >= 0.0:
            raise ValueError(f"ambient_intensity must be >= 0, got {self.ambient_intensity}")

    def ambient_radiance(self) -> np.ndarray:
        return (srgb_to_linear(self.ambient) * self.ambient_intensity).astype(np.float32)

    def lights(self) -> list:
        """The same light as [DirectionalLight, AmbientLight]: the key's irradiance is pi times
        its radiance(), so a white Lambert surface facing it still shows colour x intensity."""
        return [DirectionalLight(direction=tuple(-np.asarray(self.key.to_light)),
                                 irradiance_rgb=tuple(math.pi * self.key.radiance())),
                AmbientLight(radiance_rgb=tuple(self.ambient_radiance()))]


@dataclass(frozen=True, kw_only=True)
class HairShading:
    """Kajiya-Kay parameters. diffuse >= 0 scales sin(T, L). primary_* is the white R lobe,
    secondary_* the colour-tinted TRT lobe: strength >= 0, exponent >= 1, shift in degrees
    within [-30, 30] (Marschner: R at -5..-10, TRT at 1.5 times that with the opposite sign)."""

    diffuse: float = 1.0
    primary_strength: float = 0.35
    primary_exponent: float = 80.0
    primary_shift: float = -5.0
    secondary_strength: float = 0.5
    secondary_exponent: float = 12.0
    secondary_shift: float = 7.5

    def __post_init__(self):
        for n in ("diffuse", "primary_strength", "secondary_strength"):
            if not getattr(self, n) >= 0.0:
                raise ValueError(f"{n} must be >= 0, got {getattr(self, n)}")
        for n in ("primary_exponent", "secondary_exponent"):
            if not getattr(self, n) >= 1.0:
                raise ValueError(f"{n} must be >= 1, got {getattr(self, n)}")
        for n in ("primary_shift", "secondary_shift"):
            if not -30.0 <= getattr(self, n) <= 30.0:
                raise ValueError(f"{n} must be in [-30, 30] degrees, got {getattr(self, n)}")

    def packed(self) -> np.ndarray:
        """(8,) float32 for kernels: diffuse, R strength/exponent/shift [rad], TRT ditto, 0."""
        return np.array([self.diffuse, self.primary_strength, self.primary_exponent,
                         math.radians(self.primary_shift), self.secondary_strength,
                         self.secondary_exponent, math.radians(self.secondary_shift), 0.0],
                        dtype=np.float32)


@ti.func
def powf(x: f32, y: f32) -> f32:
    """x^y for x >= 0 in float32 (ti.pow promotes to the process's default float)."""
    return ti.select(x > 0.0, ti.exp(y * ti.log(ti.max(x, f32(1e-30)))), f32(0.0))


@ti.func
def lobe(t: vec3f, h: vec3f, shift: f32, exponent: f32) -> f32:
    """cos(theta_h - shift)^exponent with theta_h = asin(T.H), clamped at 0."""
    theta_h = ti.asin(ti.math.clamp(t.dot(h), f32(-1.0), f32(1.0)))
    return powf(ti.max(ti.cos(theta_h - shift), f32(0.0)), exponent)


@ti.func
def kajiya_kay_terms(t: vec3f, l: vec3f, v: vec3f, kk: vec8f) -> vec3f:
    """(diffuse sin(T, L), primary lobe, secondary lobe), unscaled by strengths."""
    h = unit(l + v)
    sin_tl = ti.sqrt(ti.max(f32(1.0) - t.dot(l) ** 2, f32(0.0)))
    return vec3f(sin_tl, lobe(t, h, kk[3], kk[2]), lobe(t, h, kk[6], kk[5]))


@ti.func
def shade_hair(t: vec3f, l: vec3f, v: vec3f, albedo: vec3f, light: vec3f, ambient: vec3f,
               shadow: f32, kk: vec8f) -> vec3f:
    """Outgoing linear radiance of a fibre with unit tangent t, albedo in [0, 1], key light
    irradiance `light` attenuated by `shadow` in [0, 1], and unshadowed `ambient`."""
    k = kajiya_kay_terms(t, l, v, kk)
    direct = albedo * (kk[0] * k[0]) + kk[1] * k[1] + albedo * (kk[4] * k[2])
    return albedo * ambient + light * direct * shadow


@ti.func
def shade_surface(n: vec3f, l: vec3f, v: vec3f, albedo: vec3f, light: vec3f, ambient: vec3f,
                  shadow: f32, specular: f32, shininess: f32) -> vec3f:
    """Lambert + Blinn, two-sided: n is flipped to face the eye."""
    nf = n
    if n.dot(v) < 0.0:
        nf = -n
    n_l = nf.dot(l)
    direct = vec3f(0.0, 0.0, 0.0)
    if n_l > 0.0:
        h = unit(l + v)
        spec = specular * powf(ti.max(nf.dot(h), f32(0.0)), shininess)
        direct = light * (albedo * n_l + spec) * shadow
    return albedo * ambient + direct


@ti.kernel
def shade_hair_vertices(n: ti.i32, hair: HairArgs, opacity: f32, eye: vec3f, to_light: vec3f,
                        light: vec3f, ambient: vec3f, first: ti.i32, kk: vec8f, masked: ti.i32):
    """rgba[i] (+)= (linear radiance of vertex i under one key light, plus the ambient when
    `first`, opacity), with the hair's (HairArgs) colour as albedo and its key light
    transmittance `shadow`. Tangent from the strand neighbours. masked: only vertices with
    mark[i] != 0. Shapes (V,). One thread per vertex."""
    x, nbr, albedo, shadow, mark, rgba = ti.static(hair.hair_x, hair.hair_nbr, hair.hair_colour,
                                                   hair.hair_shadow, hair.hair_mark, hair.hair_rgba)
    for i in range(n):
        if masked and mark[i] == 0:
            continue
        t = unit(x[nbr[i][1]] - x[nbr[i][0]])
        v = unit(eye - x[i])
        c = shade_hair(t, to_light, v, albedo[i], light, ambient, shadow[i], kk)
        if first:
            rgba[i] = vec4f(c[0], c[1], c[2], opacity)
        else:
            rgba[i] = rgba[i] + vec4f(c[0], c[1], c[2], 0.0)   # one thread per vertex: no atomic


@ti.kernel
def _kk_terms_kernel(n: ti.i32, t: ti.types.ndarray(dtype=vec3f, ndim=1), l: vec3f, v: vec3f,
                     kk: vec8f, out: ti.types.ndarray(dtype=vec3f, ndim=1)):
    for i in range(n):
        out[i] = kajiya_kay_terms(unit(t[i]), l, v, kk)


def kajiya_kay(tangents, to_light, to_eye, shading: HairShading = HairShading()) -> dict:
    """Evaluate the Kajiya-Kay terms in the render kernels' own code, for inspection and tests.

    tangents: (n, 3) directions (normalised here); to_light, to_eye: unit (3,) vectors.
    Returns float arrays (n,): "diffuse" = sin(T, L), "primary" and "secondary" lobes in [0, 1]
    (before strengths and colours).
    """
    ensure_init()
    t = np.atleast_2d(np.asarray(tangents, dtype=np.float32))
    unit_np = lambda a: (np.asarray(a, float) / np.linalg.norm(a)).astype(np.float32)
    out = buffer("kk_out", vec3f, (len(t),), 3)
    _kk_terms_kernel(len(t), upload("kk_t", t, vec3f, 3), unit_np(to_light), unit_np(to_eye),
                     shading.packed(), out)
    r = out.to_numpy()
    return {"diffuse": r[:, 0], "primary": r[:, 1], "secondary": r[:, 2]}


@ti.func
def mesh_sample(key: ti.i64, p2, mesh: ti.template(), eye: vec3f, to_light: vec3f, light: vec3f,
                ambient: vec3f, sview: mat4f, sproj: vec4f, sm: ti.template(), sparams: vec4f,
                first: ti.i32) -> vec3f:
    """Radiance of face key_prim(key) of the meshes (MeshArgs) seen at screen point p2 [px]:
    position, normal and colour interpolated perspective-correctly; the shadow lookup in the
    light's map (sview, sproj, sm, sparams as `shadows.filtered_transmittance` takes it)
    offset along the normal by two shadow texels against self-shadow acne."""
    screen, faces, x, normal, albedo, material = ti.static(
        mesh.mesh_screen, mesh.mesh_faces, mesh.mesh_x, mesh.mesh_normal, mesh.mesh_albedo,
        mesh.mesh_material)
    f = key_prim(key)
    ia, ib, ic = faces[f][0], faces[f][1], faces[f][2]
    w = barycentric(screen[ia], screen[ib], screen[ic], p2)
    q = perspective_weights(screen[ia], screen[ib], screen[ic], w)
    p = q[0] * x[ia] + q[1] * x[ib] + q[2] * x[ic]
    n = unit(q[0] * normal[ia] + q[1] * normal[ib] + q[2] * normal[ic])
    v = unit(eye - p)
    n_eye = ti.select(n.dot(v) < 0.0, -n, n)
    shadow = filtered_transmittance(p + n_eye * (f32(2.0) * sparams[3]), sview, sproj, sm,
                                    sparams)
    col = q[0] * albedo[ia] + q[1] * albedo[ib] + q[2] * albedo[ic]
    return shade_surface(n, to_light, v, col, light, ambient * ti.cast(first, f32), shadow,
                         material[f][0], material[f][1])


@ti.kernel
def shade_mesh(pixels: MeshPixelArgs, mesh: MeshArgs, eye: vec3f, to_light: vec3f, light: vec3f,
               ambient: vec3f, background: vec3f, sview: mat4f, sproj: vec4f, sm: ShadowMapArgs,
               sparams: vec4f, first: ti.i32):
    """base (H, W) = linear radiance of the visible mesh surface (mesh: the meshes' arrays,
    shadowed by the light's map sview, sproj, sm, sparams) over the background; with `first`
    = 0 only this light's direct term is added (one call per light). pixels: the meshes'
    depth keys mesh_key and `base` (H, W), and edge_index, sub_key: the slots of the pixels
    near mesh edges and their depth keys at the EDGE_SAMPLES^2 sub-pixel centres
    (`raster.mark_mesh_edges`, `raster.raster_edge_samples`), and each face's mesh (part).
    Edges are anti-aliased: such a pixel whose sub-pixels disagree (mesh and background, a
    depth step of over 2 %: a silhouette, or two meshes: where they cross;
    `raster.sub_pixel_edge`) is the mean of its sub-pixels, each shaded on its own face; any
    other pixel is shaded once at its centre. One thread per pixel (CPU: per row)."""
    spread_rows(pixels.pixel_base.shape[0], pixels.pixel_base.shape[1], shade_mesh_pixel,
                (pixels, mesh, eye, to_light, light, ambient, background, sview, sproj, sm, sparams,
                 first))


@ti.func
def shade_mesh_pixel(pixels: ti.template(), mesh: ti.template(), eye: vec3f, to_light: vec3f,
                     light: vec3f, ambient: vec3f, background: vec3f, sview: mat4f, sproj: vec4f,
                     sm: ti.template(), sparams: vec4f, first: ti.i32, py: ti.i32, px: ti.i32):
    """`shade_mesh` for pixel (px, py)."""
    mesh_key, edge_index, sub_key, base = ti.static(pixels.pixel_key, pixels.pixel_edge_index,
                                                    pixels.pixel_sub_key, pixels.pixel_base)
    key = mesh_key[py, px]
    slot = edge_index[py, px]
    edge, _ = sub_pixel_edge(pixels, slot)
    c = vec3f(0.0, 0.0, 0.0)
    any_mesh = key != empty_key()
    # one run-time loop over the pixel's samples (its centre, or its EDGE_SAMPLES^2
    # sub-pixels) inlines mesh_sample once; a static loop inlines it per sub-pixel, which
    # multiplies this kernel's compile on a cold cache and its front end on every start
    n_samples = 1
    weight = f32(1.0)
    if edge == 1:
        any_mesh = True
        n_samples = EDGE_SAMPLES * EDGE_SAMPLES
        weight = f32(1.0 / EDGE_SAMPLES ** 2)
    for j in range(n_samples):
        k = key
        p2 = pixel_centre(px, py)
        if edge == 1:
            k = sub_key[slot, j]
            p2 = sub_pixel_centre(px, py, j)
        if k != empty_key():
            c += weight * mesh_sample(k, p2, mesh, eye, to_light, light, ambient, sview, sproj, sm,
                                      sparams, first)
        elif first:
            c += weight * background
    if first:
        base[py, px] = c
    elif any_mesh:
        base[py, px] = base[py, px] + c   # one thread per pixel: no atomic add
