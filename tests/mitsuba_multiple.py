"""Multiple scattering in a volume of hair: ours against Mitsuba 3's path tracer.

    python tests/mitsuba_multiple.py [--out out/mitsuba_multiple] [--spp 32] [--images DIR]

needs the optional `mitsuba` package (its `scalar_rgb` variant). The scene: a dense slab of wavy strands several fibres deep (`bundle`), seen
face-on, one directional light from the front, the side or behind, black background; the
materials run from blonde to black and red (`MATERIALS`). Mitsuba renders it with its `hair`
BSDF on B-spline curves through the same points (`mitsuba_check.render_mitsuba`) at max_depth
64 (all bounces) and 2 (single scattering); ours renders it with multiple scattering and with
single scattering. Per case the table gives the mean hair luminance ratio ours / Mitsuba (all
bounces), CIEDE2000 between the mean hair colours, their hue difference [deg], the
single-scattering ratio, and each renderer's multiple-scattering gain (all bounces / single
scattering, mean luminance). Mitsuba's images are cached in --out keyed by every parameter
(delete the folder to regenerate them); --images writes one sheet of side-by-side images
(`write_sheet`: ours | Mitsuba, a row per material, a column per light, labelled).
"""

import argparse
import hashlib
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

from mitsuba_check import Scene, hair_mean_colour, render_mitsuba, render_ours  # noqa: E402

from render.camera import Camera  # noqa: E402
from render.colour import delta_e2000, linear_to_lab  # noqa: E402
from render.fibre import HairMaterial  # noqa: E402
from render.shading import DirectionalLight  # noqa: E402

MATERIALS = {
    "blonde": HairMaterial(eumelanin=0.3, pheomelanin=0.0, beta_m=0.3, beta_n=0.3),
    "light brown": HairMaterial(eumelanin=0.7, pheomelanin=0.1, beta_m=0.3, beta_n=0.3),
    "dark brown": HairMaterial(eumelanin=1.3, pheomelanin=0.0, beta_m=0.3, beta_n=0.3),
    "black": HairMaterial(eumelanin=8.0, pheomelanin=0.0, beta_m=0.3, beta_n=0.3),
    "red": HairMaterial(eumelanin=0.15, pheomelanin=1.6, beta_m=0.3, beta_n=0.3),
}
# light direction (where it travels) turned about the strands' axis y from the view's -z:
# front 20 deg, side 70 deg, back 160 deg
LIGHTS = {"front": 20.0, "side": 70.0, "back": 160.0}
MAX_DEPTH = 64
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def bundle(light_deg: float, width: int = 160, height: int = 120, n_strands: int = 4000,
           seed: int = 0) -> Scene:
    """A slab of hanging wavy strands: 4 cm across (x), 1 cm deep (z in [-1, 0] cm), 5 cm long
    (y, longer than the frame), fibres 80 um wide, so a line of sight along z crosses about
    n_strands x 80 um / 4 cm = 8 fibres; seen from +z, lit by a directional light of
    irradiance 10 W/m^2 turned `light_deg` about y from the view direction."""
    rng = np.random.default_rng(seed)
    camera = Camera(eye=(0.0, 0.0, 0.4), target=(0.0, 0.0, -0.005), fov_y=6.0, width=width,
                    height=height)
    y = np.linspace(-0.025, 0.025, 41)[None, :]
    x0 = rng.uniform(-0.02, 0.02, (n_strands, 1))
    z0 = rng.uniform(-0.01, 0.0, (n_strands, 1))
    phase = rng.uniform(0.0, 2.0 * np.pi, (n_strands, 2))
    wave = 2.0 * np.pi * y / 0.015
    x = x0 + 0.001 * np.sin(wave + phase[:, :1])
    z = z0 + 0.0007 * np.cos(0.7 * wave + phase[:, 1:])
    points = np.stack([x, np.broadcast_to(y, x.shape), z], -1)
    a = math.radians(light_deg)
    light = DirectionalLight((-math.sin(a), 0.0, -math.cos(a)), (10.0, 10.0, 10.0))
    return Scene(points, 0.00008, camera, (light,))


def _key(scene: Scene, material: HairMaterial, spp: int, max_depth: int) -> str:
    h = hashlib.sha1()
    h.update(np.ascontiguousarray(scene.points, np.float64).tobytes())
    h.update(repr((scene.width, scene.camera, scene.lights, material, spp, max_depth)).encode())
    return h.hexdigest()[:16]


def mitsuba_cached(scene: Scene, material: HairMaterial, spp: int, max_depth: int,
                   cache: Path) -> dict:
    """`render_mitsuba` through a cache file keyed by all of its inputs."""
    path = cache / f"{_key(scene, material, spp, max_depth)}.npz"
    if path.exists():
        with np.load(path) as f:
            return {"rgb": f["rgb"], "alpha": f["alpha"]}
    out = render_mitsuba(scene, material, spp, max_depth=max_depth, variant="scalar_rgb")
    cache.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, rgb=out["rgb"].astype(np.float32), alpha=out["alpha"].astype(np.float32))
    return out


def hue_difference(rgb_a, rgb_b) -> float:
    """|h_a - h_b| [deg] of the CIELAB hue angles of two linear colours, wrapped to [0, 180]."""
    la, lb = linear_to_lab(np.asarray(rgb_a)), linear_to_lab(np.asarray(rgb_b))
    d = math.degrees(math.atan2(la[2], la[1]) - math.atan2(lb[2], lb[1]))
    return abs((d + 180.0) % 360.0 - 180.0)


def compare(materials=None, lights=None, spp: int = 32, cache="out/mitsuba_multiple",
            images=None, size=(160, 120), single: bool = True, n_strands: int = 4000) -> list[dict]:
    """One dict per (material, light): mean hair colours (linear) of ours and Mitsuba's, all
    bounces and (single) single scattering, the luminance ratio, CIEDE2000, hue difference
    [deg], and (single) the single-scattering ratio and both gains. n_strands: the slab's
    strands (`bundle`; 500: a single layer)."""
    rows, cells = [], {}
    cache = Path(cache)
    materials, lights = materials or list(MATERIALS), lights or list(LIGHTS)
    for mname in materials:
        material = MATERIALS[mname]
        for lname in lights:
            scene = bundle(LIGHTS[lname], *size, n_strands=n_strands)
            ours = render_ours(scene, material, multiple_scattering=True, shadow_resolution=512)
            theirs = mitsuba_cached(scene, material, spp, MAX_DEPTH, cache)
            images_of = {"ours": ours, "mitsuba": theirs}
            if single:
                images_of["ours1"] = render_ours(scene, material, multiple_scattering=False,
                                                 shadow_resolution=512)
                images_of["mitsuba1"] = mitsuba_cached(scene, material, spp, 2, cache)
            cov = ours["alpha"]
            c = {k: hair_mean_colour(o["rgb"], cov) for k, o in images_of.items()}
            lum = {k: float(v @ LUMINANCE) for k, v in c.items()}
            row = {"material": mname, "light": lname, **c,
                   "ratio": lum["ours"] / lum["mitsuba"],
                   "delta_e": float(delta_e2000(linear_to_lab(c["ours"]), linear_to_lab(c["mitsuba"]))),
                   "hue": hue_difference(c["ours"], c["mitsuba"]),
                   "coverage_ratio": float(theirs["alpha"].sum() / cov.sum())}
            if single:
                row.update(single_ratio=lum["ours1"] / lum["mitsuba1"],
                           gain_ours=lum["ours"] / lum["ours1"],
                           gain_mitsuba=lum["mitsuba"] / lum["mitsuba1"])
            rows.append(row)
            if images is not None:
                cells[(mname, lname)] = (ours, theirs)
    if images is not None:
        write_sheet(Path(images), cells, materials, lights)
    return rows


def write_sheet(path: Path, cells: dict, materials, lights) -> None:
    """One PNG at path: a row per material, a column per light, each cell ours (left) beside
    Mitsuba's (right) at half resolution (2 x 2 box means), sRGB, one exposure per cell (the
    brighter image's 99th percentile of hair radiance maps to 1); labelled: the light over
    each column, "ours" and "Mitsuba" over its two images, the material left of each row.
    cells[(material, light)]: (ours, Mitsuba's) render dicts."""
    from mitsuba_check import encode_srgb
    from render.plot import GLYPH_H, draw_text, text_width
    from render.video import write_png

    def half(rgb):
        h, w = rgb.shape[0] // 2 * 2, rgb.shape[1] // 2 * 2
        return rgb[:h, :w].reshape(h // 2, 2, w // 2, 2, 3).mean(axis=(1, 3))

    rows, widths = [], None
    for m in materials:
        row = []
        for name in lights:
            ours, theirs = cells[(m, name)]
            hair = ours["alpha"] > 0.5
            scale = max(np.percentile(ours["rgb"][hair], 99), np.percentile(theirs["rgb"][hair], 99), 1e-6)
            a, b = half(ours["rgb"]) / scale, half(theirs["rgb"]) / scale
            row += [a, np.zeros((a.shape[0], 2, 3)), b, np.full((a.shape[0], 6, 3), 0.25)]
            widths = (a.shape[1], 2, b.shape[1], 6)
        rows += [np.concatenate(row[:-1], axis=1)]
        rows += [np.full((4, rows[-1].shape[1], 3), 0.25)]
    images = encode_srgb(np.concatenate(rows[:-1], axis=0))
    # labels in black on white: two header lines (the light at text scale 2, ours / Mitsuba at
    # 1) and a column of material names (a word a line, scale 2), left of the rows
    big, line = 2, (GLYPH_H + 3) * 2
    left = max(text_width(word, big) for m in materials for word in m.split()) + 8
    header = np.full((line + GLYPH_H + 6, left + images.shape[1], 3), 255, np.uint8)
    x = left
    for name in lights:
        a_w, gap, b_w, sep = widths
        pair = a_w + gap + b_w
        draw_text(header, x + (pair - text_width(f"{name} light", big)) // 2, 3, f"{name} light", scale=big)
        for label, x0, w in (("ours", x, a_w), ("Mitsuba", x + a_w + gap, b_w)):
            draw_text(header, x0 + (w - text_width(label, 1)) // 2, line + 2, label, scale=1)
        x += pair + sep
    body = np.full((images.shape[0], left + images.shape[1], 3), 255, np.uint8)
    body[:, left:] = images
    cell_h = (images.shape[0] + 4) // len(materials)
    for k, m in enumerate(materials):
        words = m.split()
        top = k * cell_h + (cell_h - 4 - len(words) * line) // 2
        for j, word in enumerate(words):
            draw_text(body, 4, top + j * line + 3, word, scale=big)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_png(path, np.concatenate([header, body], axis=0))


def format_table(rows) -> str:
    lines = ["| hair | light | luminance ratio | Delta E2000 | hue diff [deg] | single-scattering ratio "
             "| gain ours | gain Mitsuba |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['material']} | {r['light']} | {r['ratio']:.2f} | {r['delta_e']:.1f} "
                     f"| {r['hue']:.1f} | {r['single_ratio']:.2f} | {r['gain_ours']:.2f} "
                     f"| {r['gain_mitsuba']:.2f} |")
    return "\n".join(lines)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="out/mitsuba_multiple", help="Mitsuba image cache")
    p.add_argument("--spp", type=int, default=32)
    p.add_argument("--images", default=None,
                   help="PNG path for the sheet of side-by-side images (`write_sheet`)")
    p.add_argument("--materials", nargs="*", default=None, choices=list(MATERIALS))
    p.add_argument("--lights", nargs="*", default=None, choices=list(LIGHTS))
    p.add_argument("--strands", type=int, default=4000, help="strands in the slab (500: one layer)")
    args = p.parse_args(argv)
    from render.runtime import init
    init("cpu")
    print(format_table(compare(args.materials, args.lights, args.spp, args.out, args.images,
                               n_strands=args.strands)))


if __name__ == "__main__":
    main()
