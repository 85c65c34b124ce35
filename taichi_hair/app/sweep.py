"""`taichi-hair sweep SCENE.py --set PATH=V1,V2 ... --out DIR`: one run of the scene per point of
the cartesian product of the settings, serially or spread over a Dask cluster (`--workers N`,
`--scheduler ADDR`; one run per task, each run serial inside its worker).

    DIR/runs/<point name>/   a run's frames, MP4, state.npz, progress.json and summary.json
    DIR/sweep.csv, sweep.json the table: one row per run, its settings and figures
    DIR/contact_sheet.png     the last frame of every run, tiled in table order, each tile
                              labelled with its row number and settings (5x7 bitmap font)

A run whose summary.json exists with the same settings is finished and is not redone; a run cut
short resumes from its checkpoint. On a cluster, the workers must see the scene script and DIR at
the same paths (a shared folder), since each run writes its own folder.
"""

import csv
import io
import json
import math
import os
import time
from pathlib import Path

import numpy as np

from .settings import format_value, parse_setting, point_name, sweep_points

SUMMARY_FILE = "summary.json"
FIGURES = ("frames", "simulated_s", "substeps", "max_strain", "energy_j", "wall_s")
TILE_WIDTH = 320  # [px] contact-sheet tiles are cut down to at most this width (integer factor)


def max_strain(x, groom) -> float:
    """max |len / rest - 1| over every real edge of positions x [S, N, 3] [m] (rest: the groom)."""
    valid = np.arange(groom.max_nodes - 1)[None, :] < (groom.node_counts[:, None] - 1)
    now = np.linalg.norm(np.diff(x, axis=1), axis=2)
    rest = np.linalg.norm(np.diff(groom.positions, axis=1), axis=2)
    return float(np.abs(now[valid] / rest[valid] - 1.0).max())


def run_point(task: dict) -> dict:
    """One run of the sweep (here or on a worker): run_scene into task["dir"] with the point's
    settings (resuming a run cut short), then its summary.json, written atomically last. The
    figures: frames, simulated seconds, substeps per step, the largest edge strain seen at a
    frame's end, the total energy (kinetic + elastic + gravity) [J] at the end, wall time [s]."""
    from .runner import run_scene
    seen = {"max_strain": 0.0, "energy_j": None}

    def observe(frame, sim):
        seen["max_strain"] = max(seen["max_strain"], max_strain(sim.positions(), sim.groom))
        seen["energy_j"] = sim.total_energy()

    start = time.perf_counter()
    summary = run_scene(task["script"], task["dir"], resume=True, progress=False, overrides=task["overrides"],
                        settings=task["point"], on_frame=observe)
    figures = {"frames": summary["frames"], "simulated_s": summary["simulated_s"],
               "substeps": summary["stats"]["substeps"], **seen, "wall_s": time.perf_counter() - start}
    record = {"settings": {p: format_value(v) for p, v in task["point"].items()}, "figures": figures,
              "summary": summary}
    path = Path(task["dir"]) / SUMMARY_FILE
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(record, indent=1))
    os.replace(tmp, path)
    return record


def finished(run_dir, point: dict) -> dict | None:
    """The run's record if summary.json exists and holds these settings, else None."""
    try:
        record = json.loads((Path(run_dir) / SUMMARY_FILE).read_text())
    except (OSError, ValueError):
        return None
    same = record.get("settings") == {p: format_value(v) for p, v in point.items()}
    return record if same else None


def run_sweep(script, out_dir, settings, *, overrides=None, client=None, log=None) -> dict:
    """Every point of `settings` ([(path, values), ...]) run into out_dir/runs/<point name>
    (finished runs reused), then the table (sweep.csv, sweep.json) and the contact sheet.
    client: a dask Client to spread the runs over, or None (this process, in order)."""
    points = sweep_points(settings)
    out = Path(out_dir)
    try:
        (out / "runs").mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ValueError(f"{out}: cannot create the output folder (--out): {err.strerror or err}") from None
    script = str(Path(script).resolve())
    tasks = [{"script": script, "dir": str(out / "runs" / point_name(p)), "point": p,
              "overrides": dict(overrides or {})} for p in points]
    _check_points(script, points)
    records = [finished(t["dir"], t["point"]) for t in tasks]
    todo = [k for k, r in enumerate(records) if r is None]
    if log:
        log(f"sweep: {len(points)} runs, {len(points) - len(todo)} already finished")
    if client is None:
        results = ((k, run_point(tasks[k])) for k in todo)
    else:
        from .cluster import map_unordered
        results = ((todo[j], r) for j, r in map_unordered(client, run_point, [tasks[k] for k in todo], name="sweep"))
    for k, record in results:
        records[k] = record
        if log:
            log(f"sweep: finished {Path(tasks[k]['dir']).name} ({record['figures']['wall_s']:.1f} s)")
    rows = [{"run": k, "folder": str(Path(t["dir"]).relative_to(out)), **r["settings"], **r["figures"]}
            for k, (t, r) in enumerate(zip(tasks, records))]
    return write_results(out, [p for p, _ in settings], rows, tasks)


def _check_points(script, points):
    """Apply every point to the scene's dataclasses before anything runs, so a bad path or value
    fails at once (ValueError naming it) rather than on a worker later. Builds the scene once."""
    if not points or not points[0]:
        return
    from .runner import Shot, call_script, load_scene_module
    from ..runtime import init
    from ..world.scene import Scene
    from .settings import apply_settings
    module = load_scene_module(script)
    init(precision=getattr(module, "PRECISION", "float32"))
    scene = call_script(script, module, "build", Scene)
    shot = call_script(script, module, "shot", Shot) if callable(getattr(module, "shot", None)) else Shot()
    for point in points:
        apply_settings(scene, shot, point)


def write_results(out, paths, rows, tasks) -> dict:
    """sweep.csv, sweep.json and contact_sheet.png in out; the result dict."""
    columns = ["run", *paths, *FIGURES, "folder"]
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=columns, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    _write_text(out / "sweep.csv", text.getvalue())
    result = {"settings": paths, "figures": list(FIGURES), "rows": rows, "csv": str(out / "sweep.csv"),
              "json": str(out / "sweep.json"), "contact_sheet": str(out / "contact_sheet.png")}
    _write_text(out / "sweep.json", json.dumps(result, indent=1))
    import render
    labels = [[f"run {r['run']}"] + [f"{p.split('.')[-1]}={r[p]}" for p in paths] for r in rows]
    frames = [render.read_png(Path(t["dir"]) / "frames" / f"frame_{r['frames'] - 1:05d}.png")
              for t, r in zip(tasks, rows)]
    render.write_png(result["contact_sheet"], contact_sheet(frames, labels))
    return result


def _write_text(path, text):
    tmp = Path(str(path) + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def contact_sheet(images, labels, columns: int | None = None) -> np.ndarray:
    """Tile (H, W, 3) uint8 images (None: a grey tile) in rows of `columns` (default about
    square), each cut down by an integer factor to at most TILE_WIDTH px wide, with its label
    lines (5x7 font, upper case) in a white strip beneath. Returns the (H, W, 3) uint8 sheet."""
    from render.plot import ADVANCE, GLYPH_H, draw_text
    shape = next((a.shape for a in images if a is not None), (48, 64, 3))
    step = max(1, math.ceil(shape[1] / TILE_WIDTH))
    h, w = -(-shape[0] // step), -(-shape[1] // step)
    w = max(w, ADVANCE * max(len(line) for lines in labels for line in lines) + 4)
    strip = (GLYPH_H + 3) * max(len(lines) for lines in labels) + 4
    columns = columns or math.ceil(math.sqrt(len(images)))
    rows = math.ceil(len(images) / columns)
    pad = 4
    sheet = np.full((rows * (h + strip + pad) + pad, columns * (w + pad) + pad, 3), 255, np.uint8)
    for k, (image, lines) in enumerate(zip(images, labels)):
        top, left = pad + (k // columns) * (h + strip + pad), pad + (k % columns) * (w + pad)
        tile = np.full((h, w, 3), 128, np.uint8)
        if image is not None:
            small = image[::step, ::step, :3]
            tile[: small.shape[0], : small.shape[1]] = small
        sheet[top: top + h, left: left + w] = tile
        for j, line in enumerate(lines):
            draw_text(sheet, left + 2, top + h + 3 + j * (GLYPH_H + 3), line, (0, 0, 0), scale=1)
    return sheet


def format_sweep(result: dict) -> str:
    """The table as text."""
    paths = result["settings"]
    head = ["run", *paths, "frames", "sim s", "substeps", "max strain", "energy J", "wall s"]
    lines = ["  ".join(head)]
    for r in result["rows"]:
        cells = [str(r["run"]), *(str(r[p]) for p in paths), str(r["frames"]), f"{r['simulated_s']:.3f}",
                 str(r["substeps"]), f"{r['max_strain']:.3e}",
                 "-" if r["energy_j"] is None else f"{r['energy_j']:.4e}", f"{r['wall_s']:.1f}"]
        lines.append("  ".join(cells))
    lines.append(f"written: {result['csv']}, {result['json']}, {result['contact_sheet']}")
    return "\n".join(lines)


def add_parser(sub):
    from . import cluster
    p = sub.add_parser("sweep", help="run a scene once per point of a parameter grid; table and contact sheet")
    p.add_argument("scene", help="path of a scene script, e.g. scenes/cantilever.py")
    p.add_argument("--set", action="append", default=[], dest="settings", metavar="PATH=V1,V2,...",
                   help="a parameter and its values, e.g. material.youngs_modulus=1e9,3e9 or shot.frames=48 "
                        "(repeat for more: the cartesian product is run)")
    p.add_argument("--out", required=True, help="output directory")
    from .runner import add_image_arguments
    add_image_arguments(p)
    p.add_argument("--json", action="store_true", help="print the JSON table instead of the text one")
    p.add_argument("--no-progress", action="store_true", help="no progress lines on stderr")
    cluster.add_arguments(p)
    p.set_defaults(func=main)


def main(args) -> int:
    import sys
    from . import cluster
    from .runner import shot_overrides
    settings = [parse_setting(text) for text in args.settings]
    log = None if args.no_progress else (lambda text: print(text, file=sys.stderr, flush=True))
    if cluster.wanted(args):
        with cluster.client_from_args(args) as client:
            result = run_sweep(args.scene, args.out, settings, overrides=shot_overrides(args), client=client, log=log)
    else:
        result = run_sweep(args.scene, args.out, settings, overrides=shot_overrides(args), log=log)
    print(json.dumps(result, indent=1) if args.json else format_sweep(result))
    return 0
