"""`taichi-hair run SCENE.py --out DIR`: simulate a scene script, make dense hair, render PNG
frames and an MP4, checkpointing after every frame so a killed run resumes where it stopped.

This module is glue: it calls the `render` package for pictures (render knows nothing of
physics; nothing here rasterises).
"""

from dataclasses import dataclass
import importlib.util
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from . import cluster
from ..world.colliders import _scalar, _vec
from ..progress import ProgressBar
from ..world.scene import PROJECTIONS, STRAIN_CHOICES, Scene
from ..validation import cli_int
from .outdir import STATE_FILE, claim_out_dir, naming_file

# Image size limits: each side at most MAX_IMAGE_SIDE px, and width x height x supersample^2 (the
# pixels the rasteriser holds) at most MAX_IMAGE_PIXELS: about 75 bytes of memory per pixel (1.5 GB
# measured at 4096 x 4096), so about 5 GB at the limit (README, "Running scenes").
MAX_IMAGE_SIDE = 16384
MAX_IMAGE_PIXELS = 8192 * 8192
MAX_FRAMES = 1_000_000
MAX_DENSE = 10_000_000
PROGRESS_FILE = "progress.json"
GUIDES_DIR = "guides"  # frames simulated by a cluster run and not yet rendered


@dataclass(frozen=True, kw_only=True)
class Shot:
    """How a scene is filmed: frames at fps (one frame = 1/fps s of simulated time), the
    simulator's largest step dt [s] (at most one frame; fitted down so that whole steps fill a
    frame, see `frame_dt`), image size, a look-at camera (eye, target [m], vertical fov [deg], z up;
    None: fitted to the head and hair, seen from `view`, a direction from the subject
    towards the eye, with room for the hair to move `reach` x its longest strand sideways)
    orbiting `orbit_degrees` about the vertical through the target over the shot (a
    turntable), dense strands grown from the guides (0: draw the guides), hair colour (sRGB)
    and fibre width [m], supersampling, and what `--usd` writes: "guides" (the simulated
    strands, /Hair/Guides), "dense" (the rendered strands, /Hair/Dense) or "both"."""

    frames: int = 72
    fps: int = 24
    dt: float = 1e-3
    width: int = 640
    height: int = 480
    eye: tuple | None = None
    target: tuple | None = None
    view: tuple = (0.0, 1.0, 0.2)
    reach: float = 0.35
    fov_y: float = 35.0
    orbit_degrees: float = 0.0
    dense_strands: int = 0
    hair_colour: tuple = (0.28, 0.17, 0.09)
    hair_width: float = 1.5e-4
    supersample: int = 1
    usd: str = "guides"

    def __post_init__(self):
        for name in ("frames", "fps", "width", "height", "supersample"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 1):
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        for name in ("width", "height"):
            if getattr(self, name) > MAX_IMAGE_SIDE:
                raise ValueError(f"{name} must be at most {MAX_IMAGE_SIDE} px, got {getattr(self, name)}")
        if self.width * self.height * self.supersample ** 2 > MAX_IMAGE_PIXELS:
            raise ValueError(f"width x height x supersample^2 must be at most {MAX_IMAGE_PIXELS} pixels "
                             f"(8192 x 8192), got {self.width} x {self.height} x {self.supersample}^2")
        if self.usd not in ("guides", "dense", "both"):
            raise ValueError(f"usd must be 'guides', 'dense' or 'both', got {self.usd!r}")
        if not (isinstance(self.dense_strands, int) and self.dense_strands >= 0):
            raise ValueError(f"dense_strands must be an integer >= 0, got {self.dense_strands!r}")
        _scalar("dt", self.dt, "s", inclusive=False)
        _scalar("fov_y", self.fov_y, "degrees", inclusive=False)
        _scalar("hair_width", self.hair_width, "m", inclusive=False)
        for name in ("eye", "target"):
            if getattr(self, name) is not None:
                _vec(name, getattr(self, name))
        if (self.eye is None) != (self.target is None):
            raise ValueError("eye and target must both be given (a fixed camera) or both None (fitted)")
        _vec("view", self.view)
        _scalar("reach", self.reach, "strand lengths")
        if self.dt > 1.0 / self.fps:
            raise ValueError(f"dt must be at most one frame, 1/fps = {1.0 / self.fps:.4g} s at fps = "
                             f"{self.fps}, got {self.dt!r}")

    @property
    def steps_per_frame(self) -> int:
        """Steps per frame: the fewest steps of at most dt that fill one frame (1/fps s)."""
        return max(1, math.ceil(1.0 / (self.fps * self.dt) - 1e-9))

    @property
    def frame_dt(self) -> float:
        """The simulator's step [s]: dt fitted to the frame, 1 / (fps steps_per_frame) <= dt, so
        frame k ends at exactly k / fps (24 fps, dt 1 ms: 42 steps of 0.992 ms)."""
        return 1.0 / (self.fps * self.steps_per_frame)


def load_scene_module(path):
    """Import a scene script (a file with build() -> Scene, optionally shot() -> Shot,
    interpolator(scene, simulator) -> Interpolator, setup(scene, simulator) (called once the
    simulator exists, before a resumed run loads its checkpoint: e.g. to add pins, which
    checkpoints do not hold) and PRECISION = "float32" / "float64")."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"scene script {path} does not exist")
    spec = importlib.util.spec_from_file_location(f"taichi_hair_scene_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except (Exception, SystemExit) as err:  # the script's own error or exit: name it (--debug shows where)
        raise SceneScriptError(f"scene script {path} failed to load: {_described(err)}") from err
    if not callable(getattr(module, "build", None)):
        raise ValueError(f"scene script {path} must define build() returning a taichi_hair.Scene")
    return module


def _described(err) -> str:
    """An exception as 'Type: message'; sys.exit(code) as 'sys.exit(code)' (a script may not end the run)."""
    if isinstance(err, SystemExit):
        return f"sys.exit({err.code!r}) (a scene script may not end the run)"
    return f"{type(err).__name__}: {err}"


class SceneScriptError(ValueError):
    """A scene script that fails to load, or whose build() / shot() raises or returns the wrong
    type: a user error (the CLI prints one line; --debug shows the traceback)."""


def _call_script(script, module, name, expected):
    """module.name(), checked to be an `expected`; SceneScriptError naming the script otherwise."""
    try:
        value = getattr(module, name)()
    except ValueError:
        raise  # already names its parameter
    except (Exception, SystemExit) as err:
        raise SceneScriptError(f"scene script {script}: {name}() raised {_described(err)}") from err
    if not isinstance(value, expected):
        raise SceneScriptError(f"scene script {script}: {name}() must return a taichi_hair "
                               f"{expected.__name__}, got {type(value).__name__}")
    return value


def scalp_interpolator(scene, simulator, n_dense, seed=0):
    """Dense strands rooted on the head model's scalp, blended from the guides; dense nodes kept
    out of the cranium's ellipsoid. None when the scene has no head model."""
    from ..hair.interpolate import Interpolator
    from ..hair.roots import sample_scalp
    head = scene.head
    if head is None or head.model is None or n_dense == 0:
        return None
    groom = scene.groom
    roots = groom.positions[:, 0]
    normals = groom.positions[:, 1] - roots
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    dense_roots, _ = sample_scalp(head.model, n_dense, seed=seed + 1, blue_noise=False)
    cranium = np.ptp(head.model.vertices, axis=0) * np.array([0.5, 0.45, 0.5])
    return Interpolator(roots, normals, dense_roots, groom.max_nodes, mode="blend", blend=0.5,
                        frizz=0.0008, length_variation=0.05, seed=seed,
                        head=(np.zeros(3), cranium), head_margin=0.001)


BACKDROP = (0.32, 0.33, 0.35)  # sRGB: a neutral mid-dark grey, so that fine hair reads against it


class FrameWriter:
    """Renders one frame of hair (+ head mesh and its neck/shoulder capsules) with `render`,
    three-point lit, and writes it as a PNG."""

    def __init__(self, shot: Shot, scene):
        import render
        self.render = render
        self.shot = shot
        head = scene.head
        self.mesh = head.mesh if head is not None else None
        model = head.model if head is not None else None
        self.capsules = [render.capsule_mesh(p0, p1, r) for p0, p1, r in
                         (model.capsules if model is not None else ())]
        self.settings = render.RenderSettings(supersample=shot.supersample)
        self.base = self._fitted(scene) if shot.eye is None else render.Camera(
            eye=tuple(shot.eye), target=tuple(shot.target), up=(0.0, 0.0, 1.0), fov_y=shot.fov_y,
            width=shot.width, height=shot.height)

    def _fitted(self, scene):
        """The camera fitted to the subject: every point of the head and the rest groom inside
        the frame (`fit_camera(tight=True)`; the neck and shoulders below may leave it: head
        and hair fill it), the groom also moved by shot.reach x the longest strand either way
        across the image (moving hair; hanging hair rises as it swings, so not down); for an
        orbit, all that turned about the vertical every 15 degrees."""
        groom = scene.groom
        pts = [groom.positions[s, : groom.node_counts[s]] for s in range(groom.n_strands)]
        length = max(float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) for p in pts)
        hair = np.concatenate(pts)
        head = np.asarray(self.mesh[0]) if self.mesh is not None else hair[:1]
        allp = np.concatenate([hair, head])
        lo, hi = allp.min(axis=0), allp.max(axis=0)
        grow = self.shot.reach * length
        # room to move across the image (hair moving towards the camera hardly grows its picture)
        view = np.asarray(self.shot.view, float)
        side = np.cross(view, (0.0, 0.0, 1.0))
        side = grow * side / max(float(np.linalg.norm(side)), 1e-12)
        box = np.concatenate([head, hair - side, hair + side])
        if self.shot.orbit_degrees:
            c = 0.5 * (lo + hi)
            turn = lambda a: np.array([[math.cos(a), -math.sin(a), 0.0],
                                       [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
            box = np.concatenate([(box - c) @ turn(math.radians(a)).T + c for a in range(0, 360, 15)])
        return self.render.fit_camera(box, direction=self.shot.view, up=(0.0, 0.0, 1.0),
                                      fov_y=self.shot.fov_y, width=self.shot.width,
                                      height=self.shot.height, margin=1.02, tight=True)

    def camera(self, frame):
        angle = math.radians(self.shot.orbit_degrees * frame / max(self.shot.frames, 1))
        return self.base.orbit(math.degrees(angle)) if angle else self.base

    def write(self, path, frame, hair_points, head_pose):
        rotation, translation = head_pose
        meshes = []
        if self.mesh is not None:
            meshes.append(self.render.Mesh(vertices=np.asarray(self.mesh[0]) @ rotation.T + translation,
                                           faces=self.mesh[1]))
        for m in self.capsules:
            meshes.append(self.render.Mesh(vertices=m.vertices @ rotation.T + translation, faces=m.faces))
        camera = self.camera(frame)
        view = np.asarray(camera.eye) - np.asarray(camera.target)
        lights = self.render.three_point_lights(view, up=(0.0, 0.0, 1.0))
        hair = self.render.Hair(points=hair_points, colours=self.shot.hair_colour, widths=self.shot.hair_width)
        image = self.render.render_frame(camera, hair=hair, meshes=meshes, lights=lights,
                                         background=BACKDROP, settings=self.settings)
        self.render.write_png(path, image)


@dataclass
class PreparedRun:
    """A scene script made ready to run: its module, the scene and shot (settings and overrides
    applied), the simulator (the script's setup() done), the dense-hair interpolator (None: draw
    the guides) and the frame writer."""

    module: object
    scene: Scene
    shot: Shot
    sim: object
    interp: object
    writer: FrameWriter


def prepare_run(script, *, overrides=None, settings=None, draw=True) -> PreparedRun:
    """Load `script`, initialise Taichi in its PRECISION (once per process), build its scene and
    shot, apply `settings` ({path: value}, see taichi_hair.app.settings) and then `overrides` (Shot
    fields), and make the simulator and (draw=True) the interpolator and frame writer. Serial
    runs, cluster clients (draw=False: they only simulate) and cluster workers all start here."""
    from ..runtime import init
    from .settings import apply_settings
    from ..solver.simulator import Simulator
    module = load_scene_module(script)
    init(precision=getattr(module, "PRECISION", "float32"))
    scene = _call_script(script, module, "build", Scene)
    shot = _call_script(script, module, "shot", Shot) if callable(getattr(module, "shot", None)) else Shot()
    if settings:
        scene, shot = apply_settings(scene, shot, settings)
    if overrides:
        shot = Shot(**{**shot.__dict__, **overrides})
    sim = Simulator.from_scene(scene, dt=shot.frame_dt)
    # a frame in the fewest equal steps within the explicit bound, one substep each (a fixed dt
    # past the bound would run as substeps of up to half the bound)
    steps = sim.fit_step(1.0 / shot.fps)
    if steps != shot.steps_per_frame:
        shot = Shot(**{**shot.__dict__, "dt": 1.0 / (shot.fps * steps)})
    if callable(getattr(module, "setup", None)):
        module.setup(scene, sim)
    if not draw:
        return PreparedRun(module=module, scene=scene, shot=shot, sim=sim, interp=None, writer=None)
    interp = (module.interpolator(scene, sim) if callable(getattr(module, "interpolator", None))
              else scalp_interpolator(scene, sim, shot.dense_strands))
    return PreparedRun(module=module, scene=scene, shot=shot, sim=sim, interp=interp,
                       writer=FrameWriter(shot, scene))


def run_scene(script, out_dir, *, frames=None, resume=False, progress=True, overrides=None,
              usd=None, settings=None, on_frame=None) -> dict:
    """Simulate, interpolate and render `script` into out_dir: frames/frame_NNNNN.png, the MP4,
    state.npz (after every frame) and progress.json; with usd="usdc" or "usda" also
    <scene>.usdc / .usda, animated curves (Shot.usd says which), saved after every frame before
    the checkpoint. `settings` ({path: value}) changes the scene or shot (sweeps);
    `on_frame(frame, sim)` is called after each simulated frame. On --resume, frames a cluster
    run simulated but did not render (their guides in guides/) are rendered first. Returns the
    summary dict."""
    if usd is not None:
        _check_usd(usd)
    out, lock = claim_out_dir(out_dir, script, frames=frames, resume=resume, usd=usd)
    try:
        return _run_locked(script, out, frames, resume, progress, overrides, usd, settings, on_frame)
    finally:
        lock.close()


def _run_locked(script, out, frames, resume, progress, overrides, usd, settings, on_frame) -> dict:
    run = prepare_run(script, overrides=overrides, settings=settings)
    shot, sim = run.shot, run.sim
    total = shot.frames if frames is None else frames
    done, pending = _resume_point(out, sim, shot, total) if resume else (0, [])
    usd_writer = _usd_writer(out / f"{Path(script).stem}.{usd}", shot, run.scene, resume, done) if usd else None
    times = {"simulation": [], "interpolation": [], "rendering": []}
    with ProgressBar(total, f"{Path(script).stem}", enabled=progress, done=done - len(pending)) as bar:
        for frame in pending:
            guides, pose = load_guides(out, frame)
            render_frame(frame_path(out, frame), frame, guides, pose, run, times)
            remove_guides(out, frame)
            bar.update(1)
            if not progress:
                log_frame(frame, total, (frame + 1) / shot.fps, times, simulated=False)
        for frame in range(done, total):
            guides, pose = simulate_frame(sim, shot, times)
            hair = render_frame(frame_path(out, frame), frame, guides, pose, run, times)
            if on_frame is not None:
                on_frame(frame, sim)
            if usd_writer is not None:
                _write_usd_frame(usd_writer, frame, shot, sim, guides, hair, pose)
            _checkpoint(out, sim, shot, frame + 1)
            bar.update(1)
            if not progress:
                log_frame(frame, total, sim.time, times)
    video = write_video(out, script, shot, total)
    summary = _summary(script, total, done, times, video, sim)
    if usd_writer is not None:
        summary["usd"] = str(usd_writer.path)
    return summary


def log_frame(frame, total, t, times, simulated=True, stream=None) -> None:
    """One line on stderr for a finished frame (the progress report of --no-progress): frame
    number, simulated time [s] at its end and the wall time [ms] of its simulation,
    interpolation and rendering (a frame a cluster run simulated: rendered only)."""
    ms = {k: 1e3 * v[-1] if v else 0.0 for k, v in times.items()}
    sim = f"sim {ms['simulation']:8.1f} ms" if simulated else "sim (cluster)"
    print(f"frame {frame + 1:>{len(str(total))}}/{total}  t = {t:.4f} s  {sim}  interpolation "
          f"{ms['interpolation']:7.1f} ms  render {ms['rendering']:7.1f} ms", file=stream or sys.stderr, flush=True)


def frame_path(out, frame) -> Path:
    return Path(out) / "frames" / f"frame_{frame:05d}.png"


def guides_path(out, frame) -> Path:
    return Path(out) / GUIDES_DIR / f"frame_{frame:05d}.npz"


def save_guides(out, frame, guides, pose) -> None:
    """Write a simulated frame's guides [S, N, 3] m and head pose (R [3, 3], t [3] m) to
    guides/frame_NNNNN.npz atomically (temporary file, then rename): what a cluster run renders
    from, kept until the frame's PNG exists, so --resume can render it."""
    path = guides_path(out, frame)
    path.parent.mkdir(exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, guides=guides, rotation=pose[0], translation=pose[1])
    os.replace(tmp, path)


def load_guides(out, frame) -> tuple:
    """(guides [S, N, 3], (R, t)) saved by `save_guides`."""
    with np.load(guides_path(out, frame)) as data:
        return data["guides"], (data["rotation"], data["translation"])


def remove_guides(out, frame) -> None:
    """Drop a frame's guides once its PNG is in place (and the folder once it is empty)."""
    guides_path(out, frame).unlink(missing_ok=True)
    try:
        guides_path(out, frame).parent.rmdir()
    except OSError:  # other frames still pending, or already gone
        pass


def write_video(out, script, shot, total) -> Path:
    """The MP4 of frames 0..total-1 (read back from their PNGs), <out>/<scene>.mp4."""
    import render
    path = Path(out) / f"{Path(script).stem}.mp4"
    with naming_file(path):
        return render.write_mp4(path, (render.read_png(frame_path(out, k)) for k in range(total)), fps=shot.fps)


def _check_usd(kind):
    """ValueError (a one-line CLI error) for a bad --usd format or a missing usd-core."""
    from ..hair.usd import _pxr
    if kind not in ("usdc", "usda"):
        raise ValueError(f"--usd must be usdc or usda, got {kind!r}")
    try:
        _pxr()
    except ImportError as exc:
        raise ValueError(f"--usd: {exc}") from None


def _usd_writer(path, shot, scene, resume, done):
    """The run's UsdCurvesWriter: time code k + 1 is frame k (simulated time (k + 1) / fps); on
    --resume the file is reopened and keeps the frames the checkpoint counts."""
    from ..hair import usd
    mesh = scene.head.mesh if scene.head is not None else None
    if resume and (done > 0 or path.exists()):
        return usd.UsdCurvesWriter(path, shot.fps, resume=done)
    return usd.UsdCurvesWriter(path, shot.fps, head_mesh=mesh)


def _write_usd_frame(usd_writer, frame, shot, sim, guides, hair, pose):
    counts = sim.groom.node_counts
    sets = {}
    if shot.usd in ("guides", "both"):
        sets["Guides"] = [guides[s, : counts[s]] for s in range(sim.n_strands)]
    if shot.usd in ("dense", "both"):
        sets["Dense"] = hair
    for name in sets:
        if name not in usd_writer.counts:
            usd_writer.define(name, [len(x) for x in sets[name]], widths=shot.hair_width,
                              colours=shot.hair_colour)
    usd_writer.write_frame(frame + 1, sets, head_pose=pose)


def _checkpoint(out, sim, shot, frames_done):
    """One atomic record: the state file holds the frame count and frame step with the state
    (written to a temporary file and renamed); progress.json is a copy for people and monitors,
    also replaced atomically, never read back."""
    with naming_file(out / STATE_FILE):
        sim.save_state(out / STATE_FILE, extra={"frames_done": frames_done, "frame_dt": shot.frame_dt,
                                                 "fps": shot.fps})
    tmp = out / (PROGRESS_FILE + ".tmp")
    with naming_file(tmp):
        tmp.write_text(json.dumps({"frames_done": frames_done, "time": sim.time}))
    tmp.replace(out / PROGRESS_FILE)


def _resume_point(out, sim, shot, total=None) -> tuple:
    """(frames simulated, frames of those still to render): restore the simulator from the last
    checkpoint, after checking that the record is whole and agrees with itself and this shot
    (ValueError naming the file). A frame below the count may lack its PNG only if its guides
    are in guides/ (a cluster run renders behind the simulation)."""
    state = out / STATE_FILE
    if not state.exists():
        return 0, []
    try:
        with np.load(state) as data:
            done, frame_dt, fps, t = (int(data["extra_frames_done"]), float(data["extra_frame_dt"]),
                                      int(data["extra_fps"]), float(data["time"]))
    except KeyError:
        raise ValueError(f"{state}: the checkpoint holds no frame count (written by an older taichi_hair?); "
                         f"delete {out} to start over") from None
    except Exception as err:  # a damaged zip or array: numpy raises several types
        raise ValueError(f"{state}: not a readable checkpoint ({type(err).__name__}: {err}); "
                         f"delete {out} to start over") from None
    if (fps, frame_dt) != (shot.fps, shot.frame_dt):
        raise ValueError(f"{state}: the checkpoint was made at fps {fps} with step {frame_dt:.6g} s, this shot "
                         f"runs at fps {shot.fps} with step {shot.frame_dt:.6g} s; delete {out} to start over")
    if not (0 <= done and abs(t - done / fps) <= 1e-6 * max(1.0, t)):
        raise ValueError(f"{state}: inconsistent checkpoint: {done} frames done at fps {fps} is "
                         f"{done / fps:.6g} s, but its state is at t = {t:.6g} s; delete {out} to start over")
    if total is not None and done > total:
        raise ValueError(f"{out}: {done} frames are already finished, more than the {total} asked for "
                         f"(--resume would cut the video short): ask for {done} frames or more")
    pending = [k for k in range(done) if not frame_path(out, k).exists()]
    missing = [k for k in pending if not guides_path(out, k).exists()]
    if missing:
        raise ValueError(f"{out}: checkpoint says {done} frames are done but frame {missing[0]} is missing; "
                         f"delete {out} to start over")
    sim.load_state(state)
    return done, pending


def simulate_frame(sim, shot, times) -> tuple:
    """Step one frame; (guides [S, N, 3] m, head pose (R, t)). Appends the wall time to times."""
    start = time.perf_counter()
    sim.step(shot.steps_per_frame)
    guides = sim.positions()
    times["simulation"].append(time.perf_counter() - start)
    rotation, translation = sim.head_transform
    return guides, (np.array(rotation), np.array(translation))  # copies: the simulator moves on


def render_frame(path, frame, guides, pose, run: PreparedRun, times):
    """Interpolate the dense hair of one frame from its guides and head pose and write its PNG at
    `path`; returns the hair drawn. Appends interpolation and rendering wall times to times."""
    start = time.perf_counter()
    rotation, translation = pose
    if run.interp is not None:
        hair = run.interp.interpolate(guides, head_rotation=rotation, head_translation=translation)
    else:
        counts = run.sim.groom.node_counts
        hair = [guides[s, : counts[s]] for s in range(run.sim.n_strands)]
    times["interpolation"].append(time.perf_counter() - start)
    start = time.perf_counter()
    with naming_file(path):
        run.writer.write(path, frame, hair, (rotation, translation))
    times["rendering"].append(time.perf_counter() - start)
    return hair


def _summary(script, total, resumed_from, times, video, sim) -> dict:
    per_frame = {k: (1e3 * float(np.median(v)) if v else 0.0) for k, v in times.items()}
    return {"scene": str(script), "frames": total, "resumed_from": resumed_from, "video": str(video),
            "ms_per_frame": per_frame, "simulated_s": sim.time, "stats": sim.stats()}


def format_summary(summary: dict) -> str:
    ms = summary["ms_per_frame"]
    usd = f" + {summary['usd']}" if summary.get("usd") else ""
    if "workers" in summary:
        usd += f" ({summary['frames_rendered']} frames rendered on {summary['workers']} Dask workers)"
    resumed = f" (resumed from {summary['resumed_from']})" if summary["resumed_from"] else ""
    return (f"{summary['scene']}: {summary['frames']} frames{resumed}, "
            f"{summary['simulated_s']:.3f} s simulated -> {summary['video']}{usd}\n"
            f"median ms per frame: simulation {ms['simulation']:.1f}, interpolation "
            f"{ms['interpolation']:.1f}, rendering {ms['rendering']:.1f}")


def add_parser(sub):
    p = sub.add_parser("run", help="simulate a scene script and render frames, an MP4 and checkpoints")
    p.add_argument("scene", help="path of a scene script, e.g. scenes/shake_curly.py")
    p.add_argument("--out", default=None, help="output directory (default: out/<scene name>, e.g. out/shake_curly)")
    p.add_argument("--frames", type=cli_int("--frames", 1, MAX_FRAMES), default=None,
                   help="frames to make (default: the scene's shot)")
    p.add_argument("--resume", action="store_true", help="continue from the last checkpoint in --out")
    add_image_arguments(p)
    p.add_argument("--usd", nargs="?", const="usdc", default=None, choices=["usdc", "usda"],
                   help="also write DIR/<scene>.usdc (or .usda) of animated curves (needs the usd extra; "
                        "default: no USD; --usd alone: usdc)")
    p.add_argument("--integrator", default=None, choices=["explicit", "implicit"],
                   help="override the scene's integrator (implicit: no stability bound, docs/model.md; "
                        "default: the scene's)")
    p.add_argument("--projection", default=None, choices=PROJECTIONS,
                   help="override the explicit step's projection (shake: keeps an undamped swing's energy; "
                        "default: the scene's)")
    p.add_argument("--strain", default=None, choices=[c for c in STRAIN_CHOICES if c],
                   help="override the scene's strain measure (der: the DER measure, to compare; docs/model.md; "
                        "default: the scene's)")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress bar: one line per frame on stderr (frame, simulated time, sim / "
                        "interpolation / render ms)")
    cluster.add_arguments(p)
    p.set_defaults(func=main)


def add_image_arguments(p) -> None:
    """--width, --height (each in [1, MAX_IMAGE_SIDE] px) and --dense (in [0, MAX_DENSE])."""
    p.add_argument("--width", type=cli_int("--width", 1, MAX_IMAGE_SIDE), default=None,
                   help="image width [px] (default: the scene's shot, else 640)")
    p.add_argument("--height", type=cli_int("--height", 1, MAX_IMAGE_SIDE), default=None,
                   help="image height [px] (default: the scene's shot, else 480)")
    p.add_argument("--dense", type=cli_int("--dense", 0, MAX_DENSE), default=None,
                   help="dense strands, 0 draws the guides (default: the scene's shot)")


def shot_overrides(args) -> dict:
    """The Shot fields the command line sets (--width, --height, --dense)."""
    return {k: v for k, v in (("width", args.width), ("height", args.height),
                              ("dense_strands", args.dense)) if v is not None}


def default_out(scene) -> Path:
    """The output folder when --out is not given: out/<scene script's name>."""
    return Path("out") / Path(scene).stem


def main(args) -> int:
    if not Path(args.scene).is_file():  # before any folder is made for it
        raise ValueError(f"scene script {args.scene} does not exist")
    if args.out is None:
        args.out = str(default_out(args.scene))
    options = dict(frames=args.frames, resume=args.resume, progress=not args.no_progress,
                   overrides=shot_overrides(args),
                   settings={k: v for k, v in (("integrator", args.integrator), ("projection", args.projection),
                                               ("strain", args.strain)) if v} or None)
    if cluster.wanted(args):
        with cluster.client_from_args(args) as client:
            summary = cluster.run_scene(client, args.scene, args.out, usd=args.usd, **options)
    else:
        summary = run_scene(args.scene, args.out, usd=args.usd, **options)
    print(format_summary(summary))
    return 0
