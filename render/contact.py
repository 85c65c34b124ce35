"""A contact sheet for review: the first, middle and last frame of every run, one row each.

    python -m render.contact out/* --out out/contact_sheet.png [--thumb 320]
    python -m render.contact --run scenes/*.py --frames 24 --out docs/images/contact_sheet.png

With --run, each argument is a scene script, first run with `taichi-hair run` (as a separate
command: render imports nothing of taichi_hair) into --runs-dir/<scene> (default
out/contact_runs) at the given --frames / --width / --height / --dense, then tiled. Otherwise each argument is a run's
output folder (holding frames/frame_NNNNN.png, as `taichi-hair run` writes, or
frame_NNNNN.png directly, as `render.turntable` writes); folders without frames are skipped
with a note. Rows are labelled with the folder's name, the frame numbers and the framing over
every frame of the run (`subject_extent`): the subject's smallest fraction of the frame height,
the smallest fraction of the frame it fills (the larger of its height and width fractions: a
horizontal rod fills a frame by its width) and how many frames it touches the top, left or
right border in (a bust continues below the frame).
Measured on each frame's coverage mask (mask_NNNNN.png beside it, `taichi-hair run --masks`,
which --run asks for) where there is one, since a lit backdrop's shading and the figure's
shadow on it differ from its top-left pixel as much as the figure does; else on the frame.
"""

import argparse
from pathlib import Path

import numpy as np

from .plot import draw_text
from .video import read_png, write_png

LABEL_H = 22


def _frames(folder: Path) -> list[Path]:
    for d in (folder / "frames", folder):
        found = sorted(d.glob("frame_*.png"))
        if found:
            return found
    return []


def _thumb(image: np.ndarray, width: int) -> np.ndarray:
    """Box-filter downscale by the integer factor that brings the width to <= `width`."""
    f = max(1, -(-image.shape[1] // width))
    h, w = (image.shape[0] // f) * f, (image.shape[1] // f) * f
    a = image[:h, :w].astype(np.float32).reshape(h // f, f, w // f, f, 3).mean(axis=(1, 3))
    return (a + 0.5).astype(np.uint8)


def _subject(image: np.ndarray, tolerance: int, mask: np.ndarray | None) -> np.ndarray:
    """(H, W) bool: the pixels holding subject (see subject_extent)."""
    if mask is not None:
        if mask.shape[:2] != image.shape[:2]:
            raise ValueError(f"mask must be the image's size {image.shape[:2]}, got {mask.shape[:2]}")
        return (mask.reshape(*mask.shape[:2], -1) > tolerance).any(axis=-1)
    return np.abs(image.astype(np.int16) - image[0, 0].astype(np.int16)).max(axis=-1) > tolerance


def subject_extent(image: np.ndarray, tolerance: int = 6, mask: np.ndarray | None = None) -> tuple:
    """(height, width, inside): the fractions of the image's height and width (H, W, 3) spanned
    by the rows and columns holding subject (0 if none), and whether the subject keeps off the
    image's top, left and right borders (not the bottom: a bust continues below the frame).
    With `mask` (H, W) or (H, W, 3) uint8, the frame's coverage mask (255 where hair or meshes
    cover a pixel), the subject is the pixels over `tolerance` there; else the pixels that
    differ from the backdrop (the colour of the top-left pixel) by more than `tolerance` 8-bit
    levels in some channel (a flat backdrop only)."""
    subject = _subject(image, tolerance, mask)
    rows, cols = np.nonzero(subject.any(axis=1))[0], np.nonzero(subject.any(axis=0))[0]
    if not len(rows):
        return 0.0, 0.0, True
    h, w = subject.shape
    inside = rows[0] > 0 and cols[0] > 0 and cols[-1] < w - 1
    return float(rows[-1] - rows[0] + 1) / h, float(cols[-1] - cols[0] + 1) / w, bool(inside)


def subject_fraction(image: np.ndarray, tolerance: int = 6, mask: np.ndarray | None = None) -> float:
    """Fraction of the image's height spanned by the rows holding subject (subject_extent)."""
    return subject_extent(image, tolerance, mask)[0]


def _mask(frame: Path, shape) -> np.ndarray | None:
    """The coverage mask beside `frame` (frame_NNNNN.png -> mask_NNNNN.png), or None."""
    return read_png(frame.with_name("mask_" + frame.name.removeprefix("frame_")), shape)


def framing(frames) -> dict:
    """The framing of a run over all its frames [paths] (subject_extent on each frame's mask
    where there is one): {"height": the smallest height fraction, "fills": the smallest of
    max(height, width) fractions, "cut": frames whose subject touches the top, left or right
    border}."""
    height, fills, cut = 1.0, 1.0, 0
    for path in frames:
        image = read_png(path)
        h, w, inside = subject_extent(image, mask=_mask(path, image.shape[:2]))
        height, fills, cut = min(height, h), min(fills, max(h, w)), cut + (not inside)
    return {"height": height, "fills": fills, "cut": cut}


def contact_sheet(folders, out_path, thumb: int = 320) -> dict:
    """Write the sheet as a PNG; returns {"path", "rows": [folder names], "skipped": [...],
    "fractions": [each row's smallest subject height fraction over all its frames],
    "fills": [each row's smallest max(height, width) fraction], "cut": [each row's frames
    touching the top, left or right border]} (framing)."""
    rows, names, skipped, measures = [], [], [], []
    for folder in map(Path, folders):
        frames = _frames(folder)
        if not frames:
            skipped.append(str(folder))
            continue
        picks = sorted({0, len(frames) // 2, len(frames) - 1})
        images = [read_png(frames[k]) for k in picks]
        measure = framing(frames)
        thumbs = [_thumb(im, thumb) for im in images]
        h = max(t.shape[0] for t in thumbs)
        cells = [np.pad(t, ((0, h - t.shape[0]), (0, thumb - t.shape[1] + 4), (0, 0)),
                        constant_values=255) for t in thumbs]
        row = np.concatenate(cells, axis=1)
        label = np.full((LABEL_H, row.shape[1], 3), 255, np.uint8)
        draw_text(label, 4, 4, f"{folder.name}  frames {', '.join(frames[k].stem[6:] for k in picks)}"
                               f"  height {100 * measure['height']:.0f} %"
                               f"  fills {100 * measure['fills']:.0f} %  cut {measure['cut']}")
        rows.append(np.concatenate([label, row]))
        names.append(folder.name)
        measures.append(measure)
    if not rows:
        raise ValueError(f"no frame_*.png found in any of {[str(f) for f in folders]}")
    width = max(r.shape[1] for r in rows)
    sheet = np.concatenate([np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)),
                                   constant_values=255) for r in rows])
    path = write_png(out_path, sheet)
    return {"path": path, "rows": names, "skipped": skipped,
            "fractions": [m["height"] for m in measures], "fills": [m["fills"] for m in measures],
            "cut": [m["cut"] for m in measures]}


def run_scenes(scripts, runs_dir, frames: int, width: int, height: int, dense: int | None) -> list:
    """Run each scene script with the `taichi-hair run` command; returns the output folders
    (a scene that fails is reported and left out)."""
    import subprocess
    import sys
    folders = []
    for script in map(Path, scripts):
        out = Path(runs_dir) / script.stem
        cmd = [sys.executable, "-m", "taichi_hair", "run", str(script), "--out", str(out),
               "--frames", str(frames), "--width", str(width), "--height", str(height), "--masks"]
        if dense is not None:
            cmd += ["--dense", str(dense)]
        print(" ".join(cmd[2:]), flush=True)
        if subprocess.run(cmd).returncode == 0:
            folders.append(out)
        else:
            print(f"failed: {script}", flush=True)
    return folders


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folders", nargs="+", help="run folders, or scene scripts with --run")
    p.add_argument("--out", default="out/contact_sheet.png")
    p.add_argument("--runs-dir", default="out/contact_runs", help="where --run writes the runs")
    p.add_argument("--thumb", type=int, default=320)
    p.add_argument("--run", action="store_true", help="the arguments are scene scripts: run them first")
    p.add_argument("--frames", type=int, default=24)
    p.add_argument("--width", type=int, default=320)
    p.add_argument("--height", type=int, default=240)
    p.add_argument("--dense", type=int, default=None, help="dense strands (default: the scene's)")
    args = p.parse_args(argv)
    folders = args.folders
    if args.run:
        folders = run_scenes(folders, args.runs_dir, args.frames,
                             args.width, args.height, args.dense)
    r = contact_sheet(folders, args.out, args.thumb)
    for s in r["skipped"]:
        print(f"skipped (no frames): {s}")
    for name, f, fill, cut in zip(r["rows"], r["fractions"], r["fills"], r["cut"]):
        print(f"{name}: subject at least {100 * f:.0f} % of the frame height and fills at least "
              f"{100 * fill:.0f} % of the frame (the larger of height and width) over all frames; "
              f"touches the top, left or right border in {cut} frames")
    print(f"{r['path']}: {len(r['rows'])} rows")


if __name__ == "__main__":
    main()
