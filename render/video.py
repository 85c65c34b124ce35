"""Frames to disk: PNG, H.264 MP4, and a resumable turntable with a text progress bar.

A turntable writes frame_00000.png ... into a folder, one frame at a time and atomically
(rendered to a temporary name, then renamed), so a stopped run leaves only complete frames.
Run again, it keeps every frame whose PNG opens with the expected size and renders only the
rest; the MP4 is then assembled from all the PNGs.
"""

import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import imageio.v2 as imageio
import numpy as np

from .camera import Camera
from .frame import RenderSettings, render_frame
from .geometry import Hair
from .shading import Lighting


def _check_image(image) -> np.ndarray:
    a = np.asarray(image)
    if a.dtype != np.uint8 or a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"image must be (H, W, 3) uint8, got {a.dtype} {a.shape}")
    return a


def write_png(path, image) -> Path:
    """Write an (H, W, 3) uint8 image as PNG, atomically (temporary file, then rename)."""
    a = _check_image(image)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    # zlib level 1: 2.5x faster than the default 6 for a file about a fifth larger (frames
    # are an intermediate; the video is the product)
    imageio.imwrite(tmp, a, format="png", compress_level=1)
    os.replace(tmp, path)
    return path


def read_png(path, shape: tuple | None = None) -> np.ndarray | None:
    """The PNG at path as (H, W, 3) uint8, or None if missing, unreadable or not of `shape`."""
    try:
        a = np.asarray(imageio.imread(path, format="png"))
    except Exception:  # a truncated or foreign file is just "not a valid frame"
        return None
    if a.ndim != 3 or a.shape[2] < 3 or (shape is not None and a.shape[:2] != tuple(shape)):
        return None
    return np.ascontiguousarray(a[:, :, :3])


def write_mp4(path, frames, fps: float = 30.0, quality: float = 8.0) -> Path:
    """Encode an iterable of (H, W, 3) uint8 frames, all the same size, as H.264 MP4.

    fps > 0; quality in [0, 10] (imageio-ffmpeg's scale, 10 best). Frames are written at exactly
    their size: even sizes use yuv420p (plays everywhere); an odd width or height, which 4:2:0
    chroma cannot represent, uses yuv444p instead of being resized.
    """
    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    if not 0.0 <= quality <= 10.0:
        raise ValueError(f"quality must be in [0, 10], got {quality}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    writer, size = None, None
    try:
        for frame in frames:
            a = _check_image(frame)
            if writer is None:
                size = a.shape[:2]
                pix = "yuv420p" if size[0] % 2 == 0 and size[1] % 2 == 0 else "yuv444p"
                writer = imageio.get_writer(path, format="FFMPEG", fps=fps, codec="libx264",
                                            quality=quality, macro_block_size=1,
                                            pixelformat=pix, ffmpeg_log_level="error")
            elif a.shape[:2] != size:
                raise ValueError(f"all frames must be {size}, got {a.shape[:2]}")
            writer.append_data(a)
    finally:
        if writer is not None:
            writer.close()
    if writer is None:
        raise ValueError("frames must hold at least one frame, got none")
    return path


class ProgressBar:
    """A one-line text progress bar on stderr: done/total, rate and time left."""

    def __init__(self, total: int, label: str = "", width: int = 30, stream=None):
        self.total, self.label, self.width = max(int(total), 1), label, width
        self.stream = stream if stream is not None else sys.stderr
        self.start = time.perf_counter()
        self.done = 0

    def update(self, done: int, note: str = "") -> None:
        self.done = done
        fill = int(self.width * done / self.total)
        elapsed = time.perf_counter() - self.start
        eta = elapsed / done * (self.total - done) if done else 0.0
        self.stream.write(f"\r{self.label}[{'#' * fill}{'.' * (self.width - fill)}] "
                          f"{done}/{self.total} {elapsed:5.1f}s eta {eta:5.1f}s {note}")
        self.stream.flush()

    def close(self) -> None:
        self.stream.write("\n")
        self.stream.flush()


@dataclass(frozen=True, kw_only=True)
class Turntable:
    """A turntable shot. frames >= 1; degrees: total orbit of the camera about its target's up
    axis over the shot (the last frame stops one step short of it, so 360 loops seamlessly);
    fps > 0; quality in [0, 10] for the MP4."""

    frames: int = 48
    degrees: float = 360.0
    fps: float = 24.0
    quality: float = 8.0

    def __post_init__(self):
        if not (int(self.frames) == self.frames and self.frames >= 1):
            raise ValueError(f"frames must be an integer >= 1, got {self.frames}")
        if not np.isfinite(self.degrees):
            raise ValueError(f"degrees must be finite, got {self.degrees}")
        if not self.fps > 0:
            raise ValueError(f"fps must be > 0, got {self.fps}")
        if not 0.0 <= self.quality <= 10.0:
            raise ValueError(f"quality must be in [0, 10], got {self.quality}")


def _geometry(scene, frame: int) -> tuple[Hair | None, list]:
    """Resolve `scene` for one frame into (hair, meshes); see `turntable`."""
    value = scene(frame) if callable(scene) else scene
    if isinstance(value, Hair):
        return value, []
    if isinstance(value, tuple) and len(value) == 2:
        hair, meshes = value
        return hair, list(meshes)
    if isinstance(value, tuple) and len(value) == 4:
        points, colours, widths, meshes = value
        return Hair(points=points, colours=colours, widths=widths), list(meshes or [])
    raise ValueError("scene must be (or return) a Hair, (hair, meshes) or "
                     f"(polylines, colours, widths, meshes); got {type(value).__name__}")


def turntable(out_dir, scene, camera: Camera, *, shot: Turntable = Turntable(),
              lighting: Lighting | None = None, background=(0.82, 0.82, 0.84),
              settings: RenderSettings = RenderSettings(), video_name: str = "turntable.mp4",
              progress: bool = True, lights=None) -> dict:
    """Render a camera orbit to out_dir/frame_XXXXX.png and out_dir/video_name, resuming.

    scene: static geometry or a callable frame index -> geometry, where geometry is a Hair,
    (hair or None, meshes) or (polylines, colours, widths, meshes) as `render.Hair` takes them.
    Frames whose PNG already exists and opens at the camera's size are not rendered again
    (the callable is not called for them). lights / lighting: as `render_frame` takes them
    (fixed in the world while the camera turns). Returns {"video": Path, "frames": [Path],
    "rendered": [frame indices rendered by this call]}.
    """
    if not isinstance(shot, Turntable):
        raise ValueError(f"shot must be a render.Turntable, got {type(shot).__name__}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f"frame_{k:05d}.png" for k in range(shot.frames)]
    todo = [k for k, p in enumerate(paths) if read_png(p, (camera.height, camera.width)) is None]
    bar = ProgressBar(len(todo), label="turntable ") if progress and todo else None
    for n, k in enumerate(todo):
        hair, meshes = _geometry(scene, k)
        cam = camera.orbit(shot.degrees * k / shot.frames)
        image = render_frame(cam, hair=hair, meshes=meshes, lights=lights, lighting=lighting,
                             background=background, settings=settings)
        write_png(paths[k], image)
        if bar is not None:
            bar.update(n + 1, f"frame {k}")
    if bar is not None:
        bar.close()
    frames = (read_png(p, (camera.height, camera.width)) for p in paths)
    video = write_mp4(out / video_name, frames, fps=shot.fps, quality=shot.quality)
    return {"video": video, "frames": paths, "rendered": todo}
