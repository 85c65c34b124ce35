"""One frame: upload the scene, shadow maps, rasterise, shade, composite, encode.

The stages, in order (each a kernel or two from camera, shadows, shading and raster):
  1. light maps: hair opacity slabs and mesh depth from each directional light (`shadows`);
     stages 1-3's shading runs once per directional light, adding up;
  2. meshes: project, depth-test triangles, shade visible surfaces per pixel (Lambert + Blinn,
     shadowed) over the background;
  3. hair: project, look up each vertex's shadow, shade vertices (fibre scattering or
     Kajiya-Kay), insert segment fragments in front of the meshes into the k-buffer / tail;
  4. composite hair over meshes per pixel; box-filter supersamples; encode 8-bit sRGB.
"""

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
import taichi as ti

from .backdrop import Backdrop, camera_to_world, shade_backdrop
from .camera import Camera, f32, project_vertices, vec3f, vec4f
from .colour import srgb_colour, srgb_to_linear
from .geometry import Hair, Mesh, merge_meshes
from .raster import (EDGE_SAMPLES, clear_frame, clear_keys_2d, composite, finish,
                     mark_mesh_edges, raster_edge_samples, raster_hair, raster_triangles,
                     srgb_table, unpack_image, vec3i)
from .runtime import buffer, chunks, ensure_init, upload
from .bundles import HairArgs, LightSetArgs, MeshArgs, MeshPixelArgs
from .fibre_lobes import table_args
from .fibre_vertices import STRIDE_MAX_BEND, interpolate_skipped, mark_interpolated, shade_fibre_vertices
from .shading import DirectionalLight, HairShading, Lighting, shade_hair_vertices, shade_mesh, split_lights
from .shadows import ShadowSettings, build_shadow_map, points_shadow_terms, points_transmittance
from . import tiles
from .tiles import bin_hair, composite_binned

vec2f = ti.types.vector(2, ti.f32)
vec2i = ti.types.vector(2, ti.i32)
EMPTY_KEY = 0x7F800000 << 32  # raster.empty_key() read back: a sample no mesh covers


@dataclass(frozen=True, kw_only=True)
class RenderSettings:
    """supersample: render at s x s samples per pixel and box-filter down, s in [1, 4]; hair is
    anti-aliased by coverage already, this smooths mesh silhouettes. layers: hair fragments kept
    exactly sorted per pixel (the k-buffer's K), in [1, 16]; the rest are blended unordered
    behind them (compositor "kbuffer" only). compositor: "tiles" (default: depth-sorted
    front-to-back blending per screen tile, `render.tiles`) or "kbuffer" (the K nearest
    fragments exact, the rest an unordered tail, `raster.composite`). multiple_scattering:
    dual scattering through the hair (fibre model; False: single scattering with shadows, as a
    path tracer with max_depth 2). strand_lod in (0, 1]: level of detail for sub-pixel hair:
    render this fraction of the strands (a fixed seeded subset), widened by 1 / strand_lod, with
    their opacity lowered so that a pixel's expected transmittance is unchanged.
    shading_stride: 1 (shade every hair vertex) or 2 (fibre model: every other vertex along
    each strand, the colour of the ones between linear in arc length; about half the shading
    and shadow lookups, for segments a few pixels long or more).
    hair_model: "fibre" (physically based, `render.fibre`, from each Hair's material) or
    "kajiya_kay" (`hair_shading`'s lobes on the hair colours). shadows, hair_shading: see their
    classes."""

    supersample: int = 1
    layers: int = 4
    shadows: ShadowSettings = ShadowSettings()
    hair_shading: HairShading = HairShading()
    hair_model: str = "fibre"
    compositor: str = "tiles"
    multiple_scattering: bool = True
    strand_lod: float = 1.0
    shading_stride: int = 2

    def __post_init__(self):
        if not (int(self.supersample) == self.supersample and 1 <= self.supersample <= 4):
            raise ValueError(f"supersample must be an integer in [1, 4], got {self.supersample}")
        if not (int(self.layers) == self.layers and 1 <= self.layers <= 16):
            raise ValueError(f"layers must be an integer in [1, 16], got {self.layers}")
        if not isinstance(self.shadows, ShadowSettings):
            raise ValueError(f"shadows must be a ShadowSettings, got {type(self.shadows).__name__}")
        if not isinstance(self.hair_shading, HairShading):
            raise ValueError(f"hair_shading must be a HairShading, got {type(self.hair_shading).__name__}")
        if not 0.0 < self.strand_lod <= 1.0:
            raise ValueError(f"strand_lod must be in (0, 1], got {self.strand_lod}")
        if self.shading_stride not in (1, 2):
            raise ValueError(f"shading_stride must be 1 or 2, got {self.shading_stride}")
        if self.compositor not in ("tiles", "kbuffer"):
            raise ValueError(f"compositor must be 'tiles' or 'kbuffer', got {self.compositor!r}")
        if self.hair_model not in ("fibre", "kajiya_kay"):
            raise ValueError(f"hair_model must be 'fibre' or 'kajiya_kay', got {self.hair_model!r}")


def _padded(a: np.ndarray) -> np.ndarray:
    """Taichi ndarrays cannot be empty: give empty inputs one unused zero row."""
    return a if len(a) else np.zeros((1, *a.shape[1:]), dtype=a.dtype)


def _upload_hair(hair: Hair | None, lod: float = 1.0) -> dict:
    """The hair's strands as drawn (`Hair.subset`: a fraction `lod` of them, widened by
    1 / lod, large grooms in a spatial order; "order": each uploaded vertex's index in
    hair.vertices) on the device, with the per-vertex buffers the frame fills, and "args"
    (a HairArgs)."""
    if hair is None:
        x, w = np.zeros((0, 3), np.float32), np.zeros(0, np.float32)
        seg, nbr, col, opacity = np.zeros(0, np.int32), np.zeros((0, 2), np.int32), x, 1.0
        sigma, beta_m, order = x, w, np.zeros(0, np.int64)
    else:
        d = hair.subset(lod)
        x, w, seg, nbr = d["x"], d["widths"], d["seg"], d["nbr"]
        if lod < 1.0:
            w = w / np.float32(lod)
        col, opacity, sigma, beta_m, order = d["colour"], hair.opacity, d["sigma"], d["beta_m"], d["order"]
    nv = max(len(x), 1)
    hd = dict(x=upload("hair_x", _padded(x), vec3f, 3), width=upload("hair_w", _padded(w), f32),
              seg=upload("hair_seg", _padded(seg), ti.i32),
              nbr=upload("hair_nbr", _padded(nbr), vec2i, 2),
              colour=upload("hair_colour", _padded(col), vec3f, 3),
              sigma=upload("hair_sigma", _padded(sigma), vec3f, 3),
              beta_m=upload("hair_beta_m", _padded(beta_m), f32),
              width_px=buffer("hair_width_px", f32, (nv,)),
              screen=buffer("hair_screen", vec4f, (nv,), 4),
              shadow=buffer("hair_shadow", f32, (nv,)),
              rgba=buffer("hair_rgba", vec4f, (nv,), 4),
              mark=buffer("hair_mark", ti.i32, (nv,)))
    hd["args"] = HairArgs(**{f"hair_{name}": array for name, array in hd.items()})
    hd.update(n_vertices=len(x), n_segments=len(seg), opacity=float(opacity), order=order)
    return hd


def _upload_meshes(meshes) -> dict:
    m = merge_meshes(meshes)
    nv = max(len(m["x"]), 1)
    md = dict(x=upload("mesh_x", _padded(m["x"]), vec3f, 3),
              normal=upload("mesh_n", _padded(m["normal"]), vec3f, 3),
              colour=upload("mesh_colour", _padded(m["colour"]), vec3f, 3),
              faces=upload("mesh_faces", _padded(m["faces"]), vec3i, 3),
              material=upload("mesh_material", _padded(m["material"]), vec2f, 2),
              part=upload("mesh_part", _padded(m["part"]), ti.i32),
              width=upload("mesh_w", np.zeros(nv, np.float32), f32),
              width_px=buffer("mesh_width_px", f32, (nv,)),
              screen=buffer("mesh_screen", vec4f, (nv,), 4),
              n_vertices=len(m["x"]), n_faces=len(m["faces"]))
    md["args"] = MeshArgs(mesh_screen=md["screen"], mesh_faces=md["faces"], mesh_x=md["x"],
                          mesh_normal=md["normal"], mesh_albedo=md["colour"],
                          mesh_material=md["material"])
    return md


@ti.kernel
def lod_opacity(n: ti.i32, width_px: ti.types.ndarray(dtype=f32, ndim=1), keep: f32,
                rgba: ti.types.ndarray(dtype=vec4f, ndim=1)):
    """Strand level of detail: a kept strand of width w' = w / keep [px] stands for 1 / keep
    strands of width w, so its pixel alpha becomes c' = 1 - (1 - c)^(1 / keep), c = min(w, 1) a:
    the expected transmittance of a pixel is unchanged. One thread per vertex."""
    for i in range(n):
        w_new = width_px[i]
        c = ti.min(w_new * keep, f32(1.0)) * rgba[i][3]
        c_new = f32(1.0) - ti.exp(ti.log(ti.max(f32(1.0) - c, f32(1e-6))) / keep)
        rgba[i][3] = ti.min(c_new / ti.max(ti.min(w_new, f32(1.0)), f32(1e-6)), f32(1.0))


def _check(camera, hair, meshes, settings):
    if not isinstance(camera, Camera):
        raise ValueError(f"camera must be a render.Camera, got {type(camera).__name__}")
    if hair is not None and not isinstance(hair, Hair):
        raise ValueError(f"hair must be a render.Hair or None, got {type(hair).__name__}")
    if isinstance(meshes, Mesh) or not all(isinstance(m, Mesh) for m in meshes):
        raise ValueError("meshes must be a sequence of render.Mesh")
    if not isinstance(settings, RenderSettings):
        raise ValueError(f"settings must be a RenderSettings, got {type(settings).__name__}")


def _lights(lights, lighting) -> tuple[list, np.ndarray]:
    """(directional lights, ambient radiance (3,)) from `lights` or the older `lighting`."""
    if lights is not None and lighting is not None:
        raise ValueError("give lights=[...] or lighting=Lighting(...), not both")
    if lights is None:
        lighting = Lighting() if lighting is None else lighting
        if not isinstance(lighting, Lighting):
            raise ValueError(f"lighting must be a render.Lighting, got {type(lighting).__name__}")
        lights = lighting.lights()
    return split_lights(lights)


def _shade_hair_kajiya_kay(hd: dict, eye, light, ambient, first: bool,
                           settings: RenderSettings, smap, masked: bool):
    """Kajiya-Kay: shade the hair vertices for one directional light (adding to earlier
    lights); masked: only the vertices marked in hd["mark"]."""
    irradiance = np.asarray(light.irradiance_rgb, np.float32)
    points_transmittance(hd["n_vertices"], hd["x"], smap.view, smap.proj, smap.args(),
                         smap.params, int(masked), hd["mark"], chunks(hd["n_vertices"], 4096, 1),
                         hd["shadow"])
    shade_hair_vertices(hd["n_vertices"], hd["args"], hd["opacity"], eye, light.to_light,
                        irradiance / np.float32(np.pi), ambient, int(first),
                        settings.hair_shading.packed(), int(masked))


def _light_passes(hd, md, hair, directional, ambient, bg, eye, pixels, settings,
                  masked: bool = False, wall: dict | None = None):
    """Per directional light: its shadow maps and the meshes' shading into pixels.pixel_base
    (pixels: the meshes' MeshPixelArgs), adding up (the first pass also writes the ambient
    term and the background), and the hair's shadow terms; then the fibre shading of the hair
    under all lights in one pass (Kajiya-Kay: per light). masked: shade only the hair vertices
    marked in hd["mark"]. wall: the backdrop's kernel values (`_wall`), lit and shadowed per
    light in place of the flat background; None: the flat background."""
    passes = directional or [DirectionalLight((0.0, 0.0, -1.0), (0.0, 0.0, 0.0), shadows=False)]
    fibre = settings.hair_model == "fibre" and hd["n_vertices"] > 0
    if fibre:
        terms = buffer("hair_shadow_terms", vec3f, (len(passes), max(hd["n_vertices"], 1)), 3)
    for k, light in enumerate(passes):
        shadows = settings.shadows if light.shadows else replace(settings.shadows, enabled=False)
        smap = build_shadow_map(shadows, light.to_light, hd if hd["n_vertices"] else None,
                                md if md["n_faces"] else None)
        irradiance = np.asarray(light.irradiance_rgb, np.float32)
        sm = smap.args()
        # Lambert: radiance = albedo / pi x irradiance x cos
        shade_mesh(pixels, md["args"], eye, light.to_light, irradiance / np.float32(np.pi),
                   ambient, bg if wall is None else np.zeros(3, np.float32), smap.view, smap.proj,
                   sm, smap.params, int(k == 0))
        if wall is not None:
            shade_backdrop(pixels, wall["cam_to_world"], wall["proj"], wall["plane"],
                           wall["albedo"], light.to_light, irradiance / np.float32(np.pi),
                           ambient if k == 0 else np.zeros(3, np.float32), smap.view, smap.proj,
                           sm, smap.params)
        if fibre:
            points_shadow_terms(hd["n_vertices"], hd["x"], smap.view, smap.proj, sm, smap.params,
                                int(masked), hd["mark"], k, chunks(hd["n_vertices"], 4096, 1), terms)
        elif hd["n_vertices"]:
            _shade_hair_kajiya_kay(hd, eye, light, ambient, k == 0, settings, smap, masked)
    if fibre:
        to_light = np.array([light.to_light for light in passes], np.float32)
        irradiance = np.array([light.irradiance_rgb for light in passes], np.float32)
        lights = LightSetArgs(light_to=upload("hair_to_light", to_light, vec3f, 3),
                              light_irradiance=upload("hair_irradiance", irradiance, vec3f, 3),
                              light_terms=terms)
        shade_fibre_vertices(hd["n_vertices"], hd["args"], chunks(hd["n_vertices"], 4096, 32),
                             lights, hd["opacity"], eye, ambient,
                             int(settings.multiple_scattering),
                             np.float32(settings.shadows.density), hair.fibre.shifts(),
                             table_args(hair.fibre), int(masked))


class _Buffers(NamedTuple):
    """A rendered frame's device buffers at the camera's resolution."""

    image: object   # (H W,) packed sRGB words, row-major (`raster.finish`)
    rgb: object
    alpha: object
    mesh_key: object  # (H s, W s) the nearest mesh fragment per sample (raster.empty_key: none)


def render_buffers(camera: Camera, *, hair: Hair | None = None, meshes=(), lights=None,
                   lighting: Lighting | None = None, background=(0.82, 0.82, 0.84),
                   settings: RenderSettings = RenderSettings(),
                   backdrop: Backdrop | None = None) -> dict:
    """Render one frame and return its buffers at the camera's resolution (H, W):
    "image" (H, W, 3) uint8 sRGB, "rgb" (H, W, 3) float32 linear radiance, "alpha" (H, W)
    float32 hair opacity (0 where no hair, ~ fibre width in pixels summed over a column),
    "coverage" (H, W) float32 in [0, 1]: how much of each pixel the figure (hair and meshes)
    covers, 0 on the background or backdrop (a measure of framing that the backdrop's
    shading and the shadows on it do not enter).
    lights: a list of `DirectionalLight` and `AmbientLight`; or lighting: the older
    `Lighting` (key + ambient; the default when neither is given). background: sRGB colour in
    [0, 1] behind everything; backdrop: a lit wall (`render.Backdrop`) behind everything in its
    place, receiving the figure's shadows (None: the flat background)."""
    b = _render(camera, hair, meshes, lights, lighting, background, settings, backdrop)
    alpha = b.alpha.to_numpy()
    s = settings.supersample
    on_mesh = (b.mesh_key.to_numpy() != EMPTY_KEY).reshape(camera.height, s, camera.width, s)
    mesh = on_mesh.mean(axis=(1, 3), dtype=np.float32)
    # hair over meshes: a pixel is uncovered where both the meshes and the hair let it through
    coverage = 1.0 - (1.0 - mesh) * (1.0 - np.clip(alpha, 0.0, 1.0))
    return {"image": unpack_image(b.image, camera.height, camera.width), "rgb": b.rgb.to_numpy(), "alpha": alpha,
            "coverage": coverage.astype(np.float32)}


def _wall(backdrop: Backdrop | None, camera: Camera, scale: int) -> dict | None:
    """The backdrop's values for `backdrop.shade_backdrop` at the frame's scale, or None."""
    if backdrop is None:
        return None
    if not isinstance(backdrop, Backdrop):
        raise ValueError(f"backdrop must be a render.Backdrop or None, got {type(backdrop).__name__}")
    return dict(cam_to_world=camera_to_world(camera), proj=camera.matrices(scale)[1],
                plane=backdrop.plane(), albedo=backdrop.albedo())


def _render(camera, hair, meshes, lights, lighting, background, settings,
            backdrop=None) -> _Buffers:
    """Render one frame into device buffers (see `render_buffers`)."""
    _check(camera, hair, meshes, settings)
    wall = _wall(backdrop, camera, settings.supersample)
    directional, ambient = _lights(lights, lighting)
    bg = srgb_to_linear(srgb_colour("background", background)).astype(np.float32)
    ensure_init()
    meshes = list(meshes)
    s = settings.supersample
    height, width = camera.height * s, camera.width * s
    hd, md = _upload_hair(hair, settings.strand_lod), _upload_meshes(meshes)
    view, proj = camera.matrices(s)
    near = np.float32(camera.near)
    eye = np.asarray(camera.eye, np.float32)

    mesh_key = buffer("mesh_key", ti.i64, (height, width))
    base = buffer("base", vec3f, (height, width), 3)
    tiled = settings.compositor == "tiles"
    if tiled:
        clear_keys_2d(mesh_key)
    else:
        kbuf = buffer("kbuf", ti.i64, (height, width, settings.layers))
        tail = buffer("tail", vec4f, (height, width), 4)
        clear_frame(mesh_key, kbuf, tail)

    project_vertices(md["n_vertices"], md["x"], md["width"], view, proj, md["screen"],
                     md["width_px"])
    raster_triangles(md["n_faces"], md["screen"], md["faces"], near, mesh_key)
    # near mesh edges, the meshes' depth at sub-pixels too: where they disagree shading
    # averages them (a quarter of the pixels at most: a frame of edges is not a picture)
    edge_index = buffer("mesh_edge_index", ti.i32, (height, width))
    capacity = height * width // 4 + 1
    sub_key = buffer("mesh_sub_key", ti.i64, (capacity, EDGE_SAMPLES * EDGE_SAMPLES))
    counter = buffer("mesh_edge_count", ti.i32, (1,))
    counter.fill(0)
    mark_mesh_edges(mesh_key, capacity, counter, edge_index, sub_key, md["part"])
    raster_edge_samples(md["n_faces"], md["screen"], md["faces"], near, edge_index, sub_key)
    project_vertices(hd["n_vertices"], hd["x"], hd["width"], view, proj, hd["screen"],
                     hd["width_px"])
    # tiles: bin the hair first, marking the vertices of the segments some tile shows in front
    # of the meshes; only those are shaded
    bins = bin_hair(hd, near, mesh_key) if tiled and hd["n_vertices"] else None
    pixels = MeshPixelArgs(pixel_part=md["part"], pixel_key=mesh_key, pixel_edge_index=edge_index,
                           pixel_sub_key=sub_key, pixel_base=base)
    masked = bins is not None and tiles.CULL_HIDDEN
    strided = settings.shading_stride == 2 and settings.hair_model == "fibre" and hd["n_vertices"] > 0
    if strided:
        if not masked:
            hd["mark"].fill(1)
        mark_interpolated(hd["n_vertices"], hd["args"], np.float32(np.cos(np.radians(STRIDE_MAX_BEND))))
    _light_passes(hd, md, hair, directional, ambient, bg, eye, pixels, settings,
                  masked=masked or strided, wall=wall)
    if strided:
        interpolate_skipped(hd["n_vertices"], hd["args"])
    if settings.strand_lod < 1.0:
        lod_opacity(hd["n_vertices"], hd["width_px"], np.float32(settings.strand_lod), hd["rgba"])
    rgb_s = buffer("rgb_s", vec3f, (height, width), 3)
    alpha_s = buffer("alpha_s", f32, (height, width))
    if tiled:
        if bins is None:
            bins = bin_hair(hd, near, mesh_key)
        composite_binned(bins, hd, mesh_key, base, rgb_s, alpha_s)
    else:
        raster_hair(hd["n_segments"], hd["seg"], hd["screen"], hd["width_px"], hd["rgba"], near,
                    mesh_key, kbuf, tail)
        composite(hd["seg"], hd["screen"], hd["width_px"], hd["rgba"], kbuf, tail, base,
                  rgb_s, alpha_s)
    out_rgb = buffer("out_rgb", vec3f, (camera.height, camera.width), 3)
    out_alpha = buffer("out_alpha", f32, (camera.height, camera.width))
    image = buffer("image", ti.u32, (camera.height * camera.width,))
    finish(s, rgb_s, alpha_s, out_rgb, out_alpha, image, srgb_table())
    return _Buffers(image=image, rgb=out_rgb, alpha=out_alpha, mesh_key=mesh_key)


def render_frame(camera: Camera, *, hair: Hair | None = None, meshes=(), lights=None,
                 lighting: Lighting | None = None, background=(0.82, 0.82, 0.84),
                 settings: RenderSettings = RenderSettings(),
                 backdrop: Backdrop | None = None) -> np.ndarray:
    """Render one frame: (camera.height, camera.width, 3) uint8 sRGB. See `render_buffers`
    (this reads back the image only)."""
    image = _render(camera, hair, meshes, lights, lighting, background, settings, backdrop).image
    return unpack_image(image, camera.height, camera.width)


def hair_shadow(hair: Hair, *, meshes=(), lighting: Lighting = Lighting(),
                shadows: ShadowSettings = ShadowSettings()) -> np.ndarray:
    """Fraction of the key light reaching each hair vertex, (V,) float32 in [0, 1], in the
    order of `Hair.vertices`: the shadow term the renderer multiplies direct light by."""
    if not isinstance(hair, Hair):
        raise ValueError(f"hair must be a render.Hair, got {type(hair).__name__}")
    ensure_init()
    hd, md = _upload_hair(hair), _upload_meshes(list(meshes))
    smap = build_shadow_map(shadows, lighting.key.to_light, hd, md if md["n_faces"] else None)
    points_transmittance(hd["n_vertices"], hd["x"], smap.view, smap.proj, smap.args(),
                         smap.params, 0, hd["mark"], chunks(hd["n_vertices"], 4096, 1), hd["shadow"])
    shadow = np.empty(hd["n_vertices"], np.float32)
    shadow[hd["order"]] = hd["shadow"].to_numpy()[: hd["n_vertices"]]
    return shadow
