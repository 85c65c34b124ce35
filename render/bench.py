"""Frame-time benchmark on synthetic hair, and the synthetic scene itself.

    python -m render.bench [--strands 100000] [--segments 32] [--width 1280] [--height 720]
                           [--repeats 3] [--arch cpu] [--strand-lod 1.0]
    python -m render.bench --table [--repeats 5]     # old vs new compositor, all sizes

Times `render_frame` on whatever arch Taichi is initialised with (initialising it with
--arch if nobody has): one warm-up frame, whose time includes kernel compilation and is
reported apart, then the median of `repeats` frames. --table prints a Markdown table of the
median frame time for the k-buffer compositor (the older one), the tiled compositor, and the
tiled compositor with strand_lod 0.25, at 640x480 / 1280x720 / 1920x1080 and 20k / 100k
strands, all in the same run and with the same (fibre) shading.
"""

import argparse
import statistics
import time

import numpy as np
import taichi as ti

from .camera import Camera
from .frame import RenderSettings, render_frame
from .geometry import Hair, Mesh
from .runtime import ensure_init, init


def sphere_mesh(radius: float = 0.1, rings: int = 48, sectors: int = 96,
                colour=(0.80, 0.62, 0.52)) -> Mesh:
    """UV sphere [m] centred at the origin: a stand-in head."""
    theta = np.linspace(0.0, np.pi, rings + 1)[:, None]
    phi = np.linspace(0.0, 2.0 * np.pi, sectors + 1)[None, :]
    v = np.stack([np.sin(theta) * np.sin(phi), np.cos(theta) * np.ones_like(phi),
                  np.sin(theta) * np.cos(phi)], axis=-1).reshape(-1, 3) * radius
    i, j = np.meshgrid(np.arange(rings), np.arange(sectors), indexing="ij")
    a = (i * (sectors + 1) + j).ravel()
    b, c, d = a + sectors + 1, a + 1, a + sectors + 2
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([c, b, d], 1)])
    return Mesh(vertices=v, faces=faces, colours=colour)


def synthetic_hair(n_strands: int = 2000, n_segments: int = 32, *, radius: float = 0.1,
                   length: float = 0.22, width: float = 1e-4, seed: int = 0) -> Hair:
    """Wavy strands rooted on the upper back of a sphere of `radius` [m] at the origin,
    falling under a fake gravity and kept outside the sphere; `length` [m] per strand (+-20 %),
    `width` [m]. Brown with per-strand variation."""
    rng = np.random.default_rng(seed)
    # roots: uniform on the sphere, kept on the scalp (above the ears, not on the face)
    n = rng.normal(size=(4 * n_strands, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    scalp = (n[:, 1] > -0.1) & ~((n[:, 2] > 0.55) & (n[:, 1] < 0.55))
    n = n[scalp][:n_strands]
    s = np.linspace(0.0, 1.0, n_segments + 1)[None, :, None]
    strand_len = length * rng.uniform(0.8, 1.2, size=(len(n), 1, 1))
    down = np.array([0.0, -1.0, 0.0])
    # leave along the normal, then fall: down, and backwards for roots over the face
    fall = down[None, :] - 1.2 * np.clip(n[:, 2:3], 0.0, 1.0) * np.array([0.0, 0.0, 1.0])
    fall /= np.linalg.norm(fall, axis=1, keepdims=True)
    bend = np.clip(s * 4.0, 0.0, 1.0)
    d = (1.0 - bend) * n[:, None, :] + bend * fall[:, None, :]
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    x = radius * n[:, None, :] + np.cumsum(d * strand_len / n_segments, axis=1)
    side = np.cross(n, down)
    side /= np.maximum(np.linalg.norm(side, axis=1, keepdims=True), 1e-9)
    phase = rng.uniform(0.0, 2.0 * np.pi, size=(len(n), 1, 1))
    x += side[:, None, :] * 0.012 * np.sin(2.0 * np.pi * s * 4.0 + phase) * s
    # keep strands outside the head, each on its own shell so the hair has volume
    shell = radius * (1.01 + 0.12 * rng.uniform(size=(len(n), 1, 1)) * np.clip(s * 6, 0, 1))
    r = np.linalg.norm(x, axis=-1, keepdims=True)
    x = np.where(r < shell, x / r * shell, x)
    x[:, 0] = radius * n
    shade = rng.uniform(0.7, 1.2, size=(len(n), 1))
    colours = np.clip(np.array([0.36, 0.22, 0.12]) * shade, 0.0, 1.0)
    return Hair(points=x, colours=colours, widths=width)


def bench_render(n_strands: int = 100_000, n_segments: int = 32, width: int = 1280,
                 height: int = 720, repeats: int = 3, settings: RenderSettings = RenderSettings()) -> dict:
    """Time one frame of synthetic hair (n_strands x n_segments, 80 um fibres) on a sphere head.

    Returns {"arch", "n_strands", "n_segments", "width", "height", "first_frame_s" (includes
    kernel compilation), "compile_s" (first frame minus median), "median_ms", "frames_ms",
    "median_cpu_ms" (process CPU time, all threads: robust when other jobs share the cores)}.
    """
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    ensure_init()
    hair = synthetic_hair(n_strands, n_segments, width=8e-5)
    head = sphere_mesh()
    camera = Camera(eye=(0.05, 0.02, 0.62), target=(0.0, -0.06, 0.0), fov_y=40.0,
                    width=width, height=height)
    t0 = time.perf_counter()
    render_frame(camera, hair=hair, meshes=[head], settings=settings)
    first = time.perf_counter() - t0
    times, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        render_frame(camera, hair=hair, meshes=[head], settings=settings)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    median = statistics.median(times)
    return dict(arch=str(ti.lang.impl.current_cfg().arch).split(".")[-1], n_strands=len(hair.segments) // n_segments,
                n_segments=n_segments, width=width, height=height, first_frame_s=first,
                compile_s=max(first - median, 0.0), median_ms=median * 1e3,
                frames_ms=[t * 1e3 for t in times], median_cpu_ms=statistics.median(cpu) * 1e3)


TABLE_SETTINGS = {"kbuffer (old)": RenderSettings(compositor="kbuffer"),
                  "tiles (new)": RenderSettings(compositor="tiles"),
                  "tiles + lod 0.25": RenderSettings(compositor="tiles", strand_lod=0.25)}


def bench_table(strands=(20_000, 100_000), sizes=((640, 480), (1280, 720), (1920, 1080)),
                repeats: int = 5, n_segments: int = 32):
    """Yields one row per (strands, size), same run: {"strands", "size", and per name of
    TABLE_SETTINGS (median wall ms, median CPU ms)}."""
    for n in strands:
        for w, h in sizes:
            row = {"strands": n, "size": f"{w}x{h}"}
            for name, settings in TABLE_SETTINGS.items():
                r = bench_render(n, n_segments, w, h, repeats, settings)
                row[name] = (r["median_ms"], r["median_cpu_ms"])
            yield row


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--strands", type=int, default=100_000)
    p.add_argument("--segments", type=int, default=32)
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--height", type=int, default=720)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--arch", default="cpu")
    p.add_argument("--strand-lod", type=float, default=1.0,
                   help="RenderSettings.strand_lod: fraction of strands drawn, in (0, 1]")
    p.add_argument("--table", action="store_true", help="old vs new compositor at all sizes")
    args = p.parse_args(argv)
    if not 0.0 < args.strand_lod <= 1.0:
        p.error(f"--strand-lod must be in (0, 1], got {args.strand_lod}")
    init(args.arch)
    if args.table:
        names = list(TABLE_SETTINGS)
        print("wall ms / CPU ms (all threads), median of", args.repeats)
        print("| strands x 32 | resolution | " + " | ".join(names) + " |")
        print("|---|---|" + "---|" * len(names))
        for r in bench_table(repeats=args.repeats):
            print(f"| {r['strands'] // 1000}k | {r['size']} | "
                  + " | ".join(f"{r[k][0]:.0f} / {r[k][1]:.0f}" for k in names) + " |", flush=True)
        return
    r = bench_render(args.strands, args.segments, args.width, args.height, args.repeats,
                     RenderSettings(strand_lod=args.strand_lod))
    rows = [("arch", r["arch"]), ("strands x segments", f"{r['n_strands']} x {r['n_segments']}"),
            ("resolution", f"{r['width']} x {r['height']}"),
            ("first frame (compile + render)", f"{r['first_frame_s']:.2f} s"),
            ("compile (first - median)", f"{r['compile_s']:.2f} s"),
            ("median frame", f"{r['median_ms']:.0f} ms"),
            ("frames", ", ".join(f"{t:.0f}" for t in r["frames_ms"]) + " ms")]
    w = max(len(k) for k, _ in rows)
    for k, v in rows:
        print(f"{k:<{w}}  {v}")


if __name__ == "__main__":
    main()
