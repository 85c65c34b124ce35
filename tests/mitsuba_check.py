"""Our fibre shading against Mitsuba 3's `hair` BSDF (an independent path tracer).

    python tests/mitsuba_check.py [--out out/mitsuba] [--spp 64]

needs the optional `mitsuba` package (pip install mitsuba; the `scalar_rgb` variant is used).
Prints (a) the BSDF-level table: our h-averaged far-field scattering S(wi, wo) against
Mitsuba's `hair` BSDF evaluated on the same angles and averaged over the fibre offset h, and
(b) the image-level table: the same strands, camera, lights and parameters rendered by both
(Mitsuba with max_depth 2, single scattering; ours with shadows): the mean colour of the hair
pixels as CIELAB Delta E, and on an arc-shaped swatch of parallel fibres the positions of the
R highlight (the blue channel of red hair, where TRT is absorbed) and of the TRT highlight (red
minus blue), as the angle along the arc. Reference images are written as PNGs by this script,
never edited.
"""

import argparse
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from render.camera import Camera
from render.fibre import HairMaterial
from render.geometry import Hair, Mesh
from render.shading import AmbientLight, DirectionalLight


def _mitsuba(variant: str = "scalar_rgb"):
    import mitsuba as mi
    mi.set_variant(variant)
    return mi


def mitsuba_bsdf(material: HairMaterial):
    """Mitsuba's `hair` BSDF with the material's parameters (air outside: ior 1)."""
    return _mitsuba().load_dict(mitsuba_bsdf_dict(material))


def mitsuba_bsdf_dict(material: HairMaterial) -> dict:
    """The scene description of `mitsuba_bsdf` (loads in any variant)."""
    d = {"type": "hair", "longitudinal_roughness": material.beta_m,
         "azimuthal_roughness": material.beta_n, "scale_tilt": material.alpha_deg,
         "int_ior": material.ior, "ext_ior": 1.0}
    if material.sigma_a is None:
        d.update(eumelanin=material.eumelanin, pheomelanin=material.pheomelanin)
    else:
        d["sigma_a"] = {"type": "rgb", "value": list(material.sigma_a)}
    return d


def mitsuba_fibre_scattering(material: HairMaterial, to_light, to_eye, n_gamma: int = 128):
    """Mitsuba's hair BSDF averaged over the fibre offset h, (n, 3) [1/sr], for directions
    (n, 3) given in the fibre frame with the tangent along +y. Mitsuba's local frame has the
    tangent along y and the surface normal along z; h = sin(gamma) of the view direction, so
    both directions are turned about the tangent to put the view at each gamma (midpoints in
    gamma, weighted by dh = cos(gamma) dgamma)."""
    mi = _mitsuba()
    bsdf = mitsuba_bsdf(material)
    ctx = mi.BSDFContext()
    si = mi.SurfaceInteraction3f()
    si.sh_frame = mi.Frame3f(mi.ScalarVector3f(0.0, 0.0, 1.0))
    gammas = (np.arange(n_gamma) + 0.5) / n_gamma * np.pi - np.pi / 2
    weights = 0.5 * np.cos(gammas) * np.pi / n_gamma
    light = np.atleast_2d(np.asarray(to_light, float))
    eye = np.atleast_2d(np.asarray(to_eye, float))
    light, eye = np.broadcast_arrays(light, eye)
    out = np.zeros((len(light), 3))
    for k, (l, v) in enumerate(zip(light, eye)):
        l, v = l / np.linalg.norm(l), v / np.linalg.norm(v)
        th_l, th_v = math.asin(np.clip(l[1], -1, 1)), math.asin(np.clip(v[1], -1, 1))
        dphi = math.atan2(l[2], l[0]) - math.atan2(v[2], v[0])
        for g, w in zip(gammas, weights):
            phi_v = math.atan2(math.cos(g), -math.sin(g))
            si.wi = mi.Vector3f(math.cos(th_v) * math.cos(phi_v), math.sin(th_v),
                                math.cos(th_v) * math.sin(phi_v))
            wo = mi.Vector3f(math.cos(th_l) * math.cos(phi_v + dphi), math.sin(th_l),
                             math.cos(th_l) * math.sin(phi_v + dphi))
            out[k] += w * np.array(bsdf.eval(ctx, si, wo))
    return out


# -- scenes shared by both renderers ------------------------------------------------------

@dataclass(frozen=True)
class Scene:
    """Strands [m] (S, N, 3) with width [m], optional black sphere (centre, radius) [m],
    camera and lights: everything both renderers need."""

    points: np.ndarray
    width: float
    camera: Camera
    lights: tuple
    sphere: tuple | None = None


ARC_RADIUS, ARC_HALF = 0.05, math.radians(70.0)


def arc_swatch(light_deg: float, width: int = 192, height: int = 96) -> Scene:
    """Parallel fibres along arcs of radius 5 cm in x-z planes (hair combed over a horizontal
    rod), seen from +z, lit by a directional light turned `light_deg` about y from the view."""
    camera = Camera(eye=(0.0, 0.0, 0.5), target=(0.0, 0.0, 0.0), fov_y=7.0, width=width,
                    height=height)
    px = camera.metres_per_pixel(0.45)
    s = np.linspace(-ARC_HALF, ARC_HALF, 141)
    ys = np.arange(-12, 13) * 3.0 * px
    points = np.stack([np.stack([ARC_RADIUS * np.sin(s), np.full_like(s, y),
                                 ARC_RADIUS * np.cos(s)], -1) for y in ys])
    a = math.radians(light_deg)
    light = DirectionalLight((-math.sin(a), 0.0, -math.cos(a)), (20.0, 20.0, 20.0))
    return Scene(points, 1.5 * px, camera, (light,))


def sphere_groom(width: int = 128, height: int = 128, n: int = 40, seed: int = 0) -> Scene:
    """A small groom: n strands side by side on the upper front of a black sphere of radius
    3 cm, combed down over it, lit from the upper right and a little from behind the camera.
    The strands do not overlap on screen: where a fibre hides part of another, the visible
    part is an edge strip, brighter (grazing Fresnel) than the width average our far-field
    model assumes; Mitsuba, a near-field model, shows it (measured: +35 % with 160 crossing
    strands), so crossings would test the far-field assumption rather than the shading."""
    rng = np.random.default_rng(seed)
    r = 0.03
    camera = Camera(eye=(0.0, 0.02, 0.25), target=(0.0, 0.0, 0.0), fov_y=20.0, width=width,
                    height=height)
    u = np.linspace(-0.9, 0.9, n)
    lat0 = rng.uniform(0.3, 1.2, n)
    t = np.linspace(0.0, 1.0, 24)[None, :]
    lat = lat0[:, None] - 1.4 * t
    lon = u[:, None] * (1.0 - 0.2 * t)
    rad = r * (1.04 + 0.02 * t)
    points = np.stack([rad * np.cos(lat) * np.sin(lon), rad * np.sin(lat),
                       rad * np.cos(lat) * np.cos(lon)], -1)
    lights = (DirectionalLight((-0.5, -0.6, -0.62), (15.0, 15.0, 15.0)),)
    return Scene(points, 2.0 * camera.metres_per_pixel(0.25), camera, lights, (np.zeros(3), r))


def _sphere_mesh(centre, radius, n: int = 48) -> Mesh:
    th = np.linspace(0.0, np.pi, n + 1)[:, None]
    ph = np.linspace(0.0, 2 * np.pi, 2 * n + 1)[None, :]
    v = np.stack([np.sin(th) * np.sin(ph), np.cos(th) * np.ones_like(ph),
                  np.sin(th) * np.cos(ph)], -1).reshape(-1, 3) * radius + centre
    i, j = np.meshgrid(np.arange(n), np.arange(2 * n), indexing="ij")
    a = (i * (2 * n + 1) + j).ravel()
    b, c, d = a + 2 * n + 1, a + 1, a + 2 * n + 2
    return Mesh(vertices=v, faces=np.concatenate([np.stack([a, b, c], 1), np.stack([c, b, d], 1)]),
                colours=(0.0, 0.0, 0.0), specular=0.0)


def render_ours(scene: Scene, material: HairMaterial, supersample: int = 2,
                multiple_scattering: bool = False, shadow_resolution: int = 1024) -> dict:
    """Our render: {"rgb" (H, W, 3) linear, "alpha" (H, W)} on black; single scattering with
    shadows (maps of shadow_resolution texels a side) unless multiple_scattering."""
    from render.frame import RenderSettings, ShadowSettings, render_buffers
    hair = Hair(points=scene.points, widths=scene.width, material=material)
    meshes = [] if scene.sphere is None else [_sphere_mesh(*scene.sphere)]
    settings = RenderSettings(supersample=supersample, layers=8,
                              multiple_scattering=multiple_scattering,
                              shadows=ShadowSettings(resolution=shadow_resolution))
    return render_buffers(scene.camera, hair=hair, meshes=meshes, lights=list(scene.lights),
                          background=(0.0, 0.0, 0.0), settings=settings)


def render_mitsuba(scene: Scene, material: HairMaterial, spp: int = 64, seed: int = 0,
                   max_depth: int = 2, variant: str = "scalar_rgb") -> dict:
    """Mitsuba's render (path tracer; max_depth 2: single scattering with shadow rays, more:
    multiple scattering): {"rgb" (H, W, 3) linear, "alpha" (H, W)}; fibres are B-splines
    through our polylines."""
    mi = _mitsuba(variant)
    cam = scene.camera
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "strands.txt"
        lines = []
        for strand in scene.points:
            ext = np.concatenate([[2 * strand[0] - strand[1]], strand, [2 * strand[-1] - strand[-2]]])
            lines += [f"{x:.9g} {y:.9g} {z:.9g} {scene.width / 2:.9g}" for x, y, z in ext] + [""]
        path.write_text("\n".join(lines))
        d = {"type": "scene", "integrator": {"type": "path", "max_depth": max_depth},
             "sensor": {"type": "perspective", "fov": cam.fov_y, "fov_axis": "y",
                        "near_clip": cam.near,
                        "to_world": mi.ScalarTransform4f().look_at(origin=list(cam.eye),
                                                                   target=list(cam.target),
                                                                   up=list(cam.up)),
                        "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
                        "film": {"type": "hdrfilm", "width": cam.width, "height": cam.height,
                                 "pixel_format": "rgba", "rfilter": {"type": "box"}}},
             "hair": {"type": "bsplinecurve", "filename": str(path), "bsdf": mitsuba_bsdf_dict(material)}}
        for k, light in enumerate(scene.lights):
            if isinstance(light, DirectionalLight):
                d[f"light{k}"] = {"type": "directional", "direction": list(light.direction),
                                  "irradiance": {"type": "rgb", "value": list(light.irradiance_rgb)}}
            elif isinstance(light, AmbientLight):
                d[f"light{k}"] = {"type": "constant",
                                  "radiance": {"type": "rgb", "value": list(light.radiance_rgb)}}
        if scene.sphere is not None:
            d["sphere"] = {"type": "sphere", "center": list(scene.sphere[0]),
                           "radius": float(scene.sphere[1]),
                           "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0, 0, 0]}}}
        image = np.array(mi.render(mi.load_dict(d)))
    return {"rgb": image[..., :3], "alpha": image[..., 3]}


# -- measures -----------------------------------------------------------------------------

def linear_to_lab(rgb) -> np.ndarray:
    """CIELAB (D65, white = linear RGB (1, 1, 1)) of linear sRGB colours (..., 3)."""
    m = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
    xyz = np.asarray(rgb, float) @ m.T / m.sum(axis=1)
    f = np.where(xyz > (6 / 29) ** 3, np.cbrt(xyz), xyz / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.stack([116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]),
                     200 * (f[..., 1] - f[..., 2])], -1)


def hair_mean_colour(rgb, coverage) -> np.ndarray:
    """Mean linear colour of the hair: sum of radiance over the pixels hair touches (dilated by
    one pixel) / summed hair coverage (on a black background, so partly covered pixels count
    by their coverage)."""
    mask = coverage > 1e-3
    grown = mask.copy()
    grown[1:] |= mask[:-1]
    grown[:-1] |= mask[1:]
    grown[:, 1:] |= mask[:, :-1]
    grown[:, :-1] |= mask[:, 1:]
    return rgb[grown].sum(axis=0) / coverage.sum()


def delta_e(rgb_a, rgb_b) -> float:
    """CIE76 Delta E between two linear colours."""
    return float(np.linalg.norm(linear_to_lab(rgb_a) - linear_to_lab(rgb_b)))


def arc_profile(out: dict, scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """(arc angle s [deg] of each image column, mean hair colour of that column (W, 3))."""
    cam = scene.camera
    s = np.linspace(-ARC_HALF, ARC_HALF, 2001)
    sx = cam.project(np.stack([ARC_RADIUS * np.sin(s), 0 * s, ARC_RADIUS * np.cos(s)], -1))[:, 0]
    cols = np.arange(cam.width) + 0.5
    angle = np.degrees(np.interp(cols, sx, s, left=np.nan, right=np.nan))
    cov = out["alpha"].sum(axis=0)
    colour = out["rgb"].sum(axis=0) / np.maximum(cov, 1e-9)[:, None]
    colour[cov < 0.5 * np.nanmax(cov)] = np.nan
    return angle, colour


def peak(angle, values, smooth: int = 2) -> float:
    """Angle [deg] of the maximum of a profile: box-smoothed, then a parabola through the
    highest sample and its neighbours."""
    ok = np.isfinite(values) & np.isfinite(angle)
    a, v = angle[ok], values[ok]
    if smooth:
        kernel = np.ones(2 * smooth + 1) / (2 * smooth + 1)
        v = np.convolve(np.pad(v, smooth, mode="edge"), kernel, mode="valid")
    k = int(np.clip(np.argmax(v), 1, len(v) - 2))
    y0, y1, y2 = v[k - 1], v[k], v[k + 1]
    den = y0 - 2 * y1 + y2
    off = 0.5 * (y0 - y2) / den if den < 0 else 0.0
    return float(a[k] + off * (a[k + 1] - a[k - 1]) / 2)


RED_HAIR = HairMaterial(eumelanin=0.15, pheomelanin=1.6, beta_m=0.15, beta_n=0.3, alpha_deg=3.0)
BROWN_HAIR = HairMaterial(eumelanin=1.3, pheomelanin=0.2, beta_m=0.3, beta_n=0.3, alpha_deg=2.0)
BLONDE_HAIR = HairMaterial(eumelanin=0.25, pheomelanin=0.15, beta_m=0.25, beta_n=0.4, alpha_deg=2.0)


def compare_images(spp: int = 64, out_dir=None, lights_deg=(-20.0, 0.0, 25.0),
                   size=(192, 96)) -> list[dict]:
    """Render every comparison scene with both renderers; one dict per image with the mean
    hair colours (linear), Delta E, and for the swatches the R / TRT highlight angles [deg]."""
    rows = []
    cases = [(f"swatch, light {d:+.0f} deg", arc_swatch(d, *size), RED_HAIR) for d in lights_deg]
    cases += [("groom on sphere, brown", sphere_groom(), BROWN_HAIR),
              ("groom on sphere, blonde", sphere_groom(), BLONDE_HAIR)]
    for name, scene, material in cases:
        ours, theirs = render_ours(scene, material), render_mitsuba(scene, material, spp)
        row = {"name": name, "ours": hair_mean_colour(ours["rgb"], ours["alpha"]),
               "mitsuba": hair_mean_colour(theirs["rgb"], ours["alpha"]),
               "coverage_ratio": float(theirs["alpha"].sum() / ours["alpha"].sum())}
        row["delta_e"] = delta_e(row["ours"], row["mitsuba"])
        if name.startswith("swatch"):
            for key, out in (("ours", ours), ("mitsuba", theirs)):
                angle, colour = arc_profile(out, scene)
                row[f"r_{key}"] = peak(angle, colour[:, 2])
                row[f"trt_{key}"] = peak(angle, colour[:, 0] - colour[:, 2])
        if out_dir is not None:
            from render.video import write_png
            out_dir = Path(out_dir)
            slug = name.replace(" ", "_").replace(",", "").replace("+", "p").replace("-", "m")
            for key, out in (("ours", ours), ("mitsuba", theirs)):
                write_png(out_dir / f"{slug}_{key}.png", encode_srgb(out["rgb"]))
        rows.append(row)
    return rows


def encode_srgb(rgb) -> np.ndarray:
    """8-bit sRGB (..., 3) of linear colours, clipped to [0, 1]."""
    c = np.clip(rgb, 0.0, 1.0)
    s = np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)
    return (s * 255 + 0.5).astype(np.uint8)


def bsdf_table() -> list[dict]:
    """Max and mean relative error of our S against Mitsuba's over a grid of 125 angle
    triples (theta_i, theta_o, phi), per material."""
    from render.fibre_lobes import fibre_scattering
    g = np.radians(np.array([(a, b, c) for a in (-60, -30, 0, 20, 45) for b in (-50, -20, 0, 10, 40)
                             for c in (0, 45, 90, 150, 180)], float))
    light = np.stack([np.cos(g[:, 0]) * np.cos(g[:, 2]), np.sin(g[:, 0]),
                      np.cos(g[:, 0]) * np.sin(g[:, 2])], -1)
    eye = np.stack([np.cos(g[:, 1]), np.sin(g[:, 1]), 0 * g[:, 1]], -1)
    rows = []
    for name, m in (("red", RED_HAIR), ("brown", BROWN_HAIR), ("blonde", BLONDE_HAIR),
                    ("black, rough", HairMaterial(eumelanin=8.0, beta_m=0.6, beta_n=0.7))):
        ours = fibre_scattering(m, (0.0, 1.0, 0.0), light, eye)["S"]
        theirs = mitsuba_fibre_scattering(m, light, eye)
        err = np.abs(ours - theirs) / np.maximum(np.abs(theirs), 0.02 * theirs.max())
        rows.append({"material": name, "max": float(err.max()), "mean": float(err.mean())})
    return rows


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="out/mitsuba")
    p.add_argument("--spp", type=int, default=64)
    args = p.parse_args(argv)
    from render.runtime import init
    init("cpu")
    print("BSDF level (relative error, |S| floored at 2 % of its maximum):")
    for r in bsdf_table():
        print(f"  {r['material']:<14} max {100 * r['max']:5.2f} %   mean {100 * r['mean']:5.2f} %")
    print("image level (mean hair colour, linear RGB; highlight angles along the arc, deg):")
    for r in compare_images(args.spp, args.out):
        line = (f"  {r['name']:<26} ours {np.round(r['ours'], 4)} mitsuba {np.round(r['mitsuba'], 4)}"
                f"  dE {r['delta_e']:.2f}  coverage ratio {r['coverage_ratio']:.3f}")
        if "r_ours" in r:
            line += (f"  R {r['r_ours']:+.2f}/{r['r_mitsuba']:+.2f}"
                     f"  TRT {r['trt_ours']:+.2f}/{r['trt_mitsuba']:+.2f}")
        print(line)


if __name__ == "__main__":
    main()
