"""A serial run of a scene script (`taichi-hair run`, run_command.py): simulate it, make dense
hair, render PNG frames and an MP4, checkpointing after every frame so a killed run resumes where
it stopped (the output folder's files: run_output.py).

This module is glue: it calls the `render` package for pictures (render knows nothing of
physics; nothing here rasterises).
"""

from dataclasses import dataclass
import importlib.util
import math
import time
from pathlib import Path

import numpy as np

from ..progress import ProgressBar
from ..world.scene import Scene
from ..validation import choice, cli_int, integer, real, vector3
from .figure import hard_base, seam_normals
from .outdir import claim_out_dir, naming_file
from .run_output import (check_usd, checkpoint, frame_path, load_guides, log_frame, open_usd_writer,
                         remove_guides, resume_point, run_summary, write_usd_frame, write_video)

# Image size limits: each side at most MAX_IMAGE_SIDE px, and width x height x supersample^2 (the
# pixels the rasteriser holds) at most MAX_IMAGE_PIXELS: about 75 bytes of memory per pixel (1.5 GB
# measured at 4096 x 4096), so about 5 GB at the limit (README, "Running scenes").
MAX_IMAGE_SIDE = 16384
MAX_IMAGE_PIXELS = 8192 * 8192
MAX_FRAMES = 1_000_000
MAX_DENSE = 10_000_000


@dataclass(frozen=True, kw_only=True)
class Shot:
    """How a scene is filmed: frames at fps (one frame = 1/fps s of simulated time), the
    simulator's largest step dt [s] (at most one frame; fitted down so that whole steps fill a
    frame, see `frame_dt`), image size, a look-at camera (eye, target [m], vertical fov [deg], z up;
    None: fitted to the head and hair, seen from `view`, a direction from the subject
    towards the eye, with room for the hair to move `reach` x its longest strand sideways)
    orbiting `orbit_degrees` about the vertical through the target over the shot (a
    turntable), dense strands grown from the guides (0: draw the guides), hair colour (sRGB)
    and fibre width [m], supersampling, what `--usd` writes: "guides" (the simulated
    strands, /Hair/Guides), "dense" (the rendered strands, /Hair/Dense) or "both", and the
    backdrop: "wall" (a matte wall WALL_DISTANCE behind the target, facing the camera, that
    the figure casts its key light shadow on) or "plain" (a flat colour). masks: also write
    each frame's coverage mask (frames/mask_NNNNN.png, `mask_path`: grey, 255 where the hair
    and meshes cover a pixel, 0 on the backdrop), which framing measures read
    (render.contact) since the lit wall and its shadows differ from a flat backdrop too."""

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
    backdrop: str = "wall"
    masks: bool = False

    def __post_init__(self):
        for name in ("frames", "fps", "width", "height", "supersample"):
            integer(name, getattr(self, name), low=1)
        for name in ("width", "height"):
            if getattr(self, name) > MAX_IMAGE_SIDE:
                raise ValueError(f"{name} must be at most {MAX_IMAGE_SIDE} px, got {getattr(self, name)}")
        if self.width * self.height * self.supersample ** 2 > MAX_IMAGE_PIXELS:
            raise ValueError(f"width x height x supersample^2 must be at most {MAX_IMAGE_PIXELS} pixels "
                             f"(8192 x 8192), got {self.width} x {self.height} x {self.supersample}^2")
        choice("usd", self.usd, ("guides", "dense", "both"))
        choice("backdrop", self.backdrop, ("wall", "plain"))
        choice("masks", self.masks, (False, True))
        integer("dense_strands", self.dense_strands, low=0)
        real("dt", self.dt, "s", low=0.0, low_open=True)
        real("fov_y", self.fov_y, "degrees", low=0.0, low_open=True)
        real("hair_width", self.hair_width, "m", low=0.0, low_open=True)
        for name in ("eye", "target"):
            if getattr(self, name) is not None:
                vector3(name, getattr(self, name))
        if (self.eye is None) != (self.target is None):
            raise ValueError("eye and target must both be given (a fixed camera) or both None (fitted)")
        vector3("view", self.view)
        real("reach", self.reach, "strand lengths", low=0.0)
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


def call_script(script, module, name, expected):
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
# the wall backdrop: its albedo (sRGB; lit by the three-point lights it reads about as BACKDROP
# where the key light reaches it) and its distance [m] behind the camera's target, behind the
# head and shoulders, near enough that the key light's shadow of the figure falls in frame
WALL = (0.26, 0.265, 0.28)
WALL_DISTANCE = 0.3


class FrameWriter:
    """Renders one frame of hair (+ the head mesh and its neck capsule, turned with the head, and
    the body: where it is, or turned with the head; Head.body_attached) with `render`,
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
        body = head.body if head is not None else None
        self.body = None
        if body is not None:
            drawn = hard_base(*body)
            smooth = render.geometry.vertex_normals(drawn["vertices"], drawn["faces"])
            self.body = render.Mesh(**drawn, normals=seam_normals(drawn["vertices"], smooth,
                                                                  model.capsules if model is not None else ()))
        self.body_turns = head is not None and head.body_attached == "head"
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

    def wall(self, camera):
        """The shot's backdrop for `camera`: a vertical wall facing it WALL_DISTANCE behind its
        target (render.Backdrop), or None for the plain one."""
        if self.shot.backdrop != "wall":
            return None
        view = np.asarray(camera.eye) - np.asarray(camera.target)
        level = np.array([view[0], view[1], 0.0])
        # a camera looking straight down or up: the wall faces it
        normal = level if np.linalg.norm(level) > 1e-3 * np.linalg.norm(view) else view
        normal = normal / np.linalg.norm(normal)
        return self.render.Backdrop(point=tuple(np.asarray(camera.target) - WALL_DISTANCE * normal),
                                    normal=tuple(normal), colour=WALL)

    def write(self, path, frame, hair_points, head_pose):
        rotation, translation = head_pose
        meshes = []
        if self.mesh is not None:
            meshes.append(self.render.Mesh(vertices=np.asarray(self.mesh[0]) @ rotation.T + translation,
                                           faces=self.mesh[1]))
        for m in self.capsules:
            meshes.append(self.render.Mesh(vertices=m.vertices @ rotation.T + translation, faces=m.faces))
        if self.body is not None:
            meshes.append(self.render.Mesh(vertices=self.body.vertices @ rotation.T + translation, faces=self.body.faces)
                          if self.body_turns else self.body)
        camera = self.camera(frame)
        view = np.asarray(camera.eye) - np.asarray(camera.target)
        lights = self.render.three_point_lights(view, up=(0.0, 0.0, 1.0))
        hair = self.render.Hair(points=hair_points, colours=self.shot.hair_colour, widths=self.shot.hair_width)
        scene = dict(hair=hair, meshes=meshes, lights=lights, background=BACKDROP,
                     settings=self.settings, backdrop=self.wall(camera))
        if not self.shot.masks:
            self.render.write_png(path, self.render.render_frame(camera, **scene))
            return
        buffers = self.render.render_buffers(camera, **scene)
        self.render.write_png(path, buffers["image"])
        grey = np.rint(255.0 * buffers["coverage"]).astype(np.uint8)
        self.render.write_png(mask_path(path), np.repeat(grey[..., None], 3, axis=2))


def mask_path(frame_png) -> Path:
    """The coverage mask written beside a frame: frames/frame_NNNNN.png -> frames/mask_NNNNN.png."""
    frame_png = Path(frame_png)
    return frame_png.with_name("mask_" + frame_png.name.removeprefix("frame_"))


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
    scene = call_script(script, module, "build", Scene)
    shot = call_script(script, module, "shot", Shot) if callable(getattr(module, "shot", None)) else Shot()
    if settings:
        scene, shot = apply_settings(scene, shot, settings)
    if overrides:
        shot = Shot(**{**shot.__dict__, **overrides})
    sim = Simulator.from_scene(scene, dt=shot.frame_dt)
    if callable(getattr(module, "setup", None)):
        module.setup(scene, sim)  # first: the pins it adds change how the steps are fitted
    # a frame in the equal steps within the explicit bound that take the fewest strand steps (a
    # fixed dt past the bound would run as substeps of up to half the bound)
    steps = sim.fit_step(1.0 / shot.fps)
    if steps != shot.steps_per_frame:
        shot = Shot(**{**shot.__dict__, "dt": 1.0 / (shot.fps * steps)})
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
        check_usd(usd)
    out, lock = claim_out_dir(out_dir, script, frames=frames, resume=resume, usd=usd)
    try:
        return _run_locked(script, out, frames, resume, progress, overrides, usd, settings, on_frame)
    finally:
        lock.close()


def _run_locked(script, out, frames, resume, progress, overrides, usd, settings, on_frame) -> dict:
    run = prepare_run(script, overrides=overrides, settings=settings)
    shot, sim = run.shot, run.sim
    total = shot.frames if frames is None else frames
    done, pending = resume_point(out, sim, shot, total) if resume else (0, [])
    usd_writer = open_usd_writer(out / f"{Path(script).stem}.{usd}", shot, run.scene, resume, done) if usd else None
    times = {"simulation": [], "interpolation": [], "rendering": []}
    with ProgressBar(total, f"{Path(script).stem}", enabled=progress, done=done - len(pending)) as bar:
        for frame in pending:
            render_frame(frame_path(out, frame), frame, *load_guides(out, frame), run, times)
            remove_guides(out, frame)
            bar.update(1)
            if not progress:
                log_frame(frame, total, (frame + 1) / shot.fps, times, simulated=False)
        for frame in range(done, total):
            guides, pose, directors = simulate_frame(sim, shot, times, needs_directors(run))
            hair = render_frame(frame_path(out, frame), frame, guides, pose, directors, run, times)
            if on_frame is not None:
                on_frame(frame, sim)
            if usd_writer is not None:
                write_usd_frame(usd_writer, frame, shot, sim, guides, hair, pose)
            checkpoint(out, sim, shot, frame + 1)
            bar.update(1)
            if not progress:
                log_frame(frame, total, sim.time, times)
    video = write_video(out, script, shot, total)
    summary = run_summary(script, total, done, times, video, sim)
    if usd_writer is not None:
        summary["usd"] = str(usd_writer.path)
    return summary


def needs_directors(run: PreparedRun) -> bool:
    """Whether the run's interpolator turns dense edges with the guides' material frames (an
    imported style built by `style_interpolator`), so each frame must carry them."""
    return bool(getattr(run.interp, "needs_directors", False))


def simulate_frame(sim, shot, times, directors=False) -> tuple:
    """Step one frame; (guides [S, N, 3] m, head pose (R, t), the guides' first material
    directors [S, N-1, 3] when `directors`, else None). Appends the wall time to times."""
    start = time.perf_counter()
    sim.step(shot.steps_per_frame)
    guides = sim.positions()
    m1 = sim.material_directors() if directors else None
    times["simulation"].append(time.perf_counter() - start)
    rotation, translation = sim.head_transform
    return guides, (np.array(rotation), np.array(translation)), m1  # copies: the simulator moves on


def render_frame(path, frame, guides, pose, directors, run: PreparedRun, times):
    """Interpolate the dense hair of one frame from its guides, head pose and (None unless the
    interpolator needs them) the guides' material directors, and write its PNG at `path`;
    returns the hair drawn. Appends interpolation and rendering wall times to times."""
    start = time.perf_counter()
    rotation, translation = pose
    if run.interp is not None:
        hair = run.interp.interpolate(guides, head_rotation=rotation, head_translation=translation,
                                      directors=directors)
    else:
        counts = run.sim.groom.node_counts
        hair = [guides[s, : counts[s]] for s in range(run.sim.n_strands)]
    times["interpolation"].append(time.perf_counter() - start)
    start = time.perf_counter()
    with naming_file(path):
        run.writer.write(path, frame, hair, (rotation, translation))
    times["rendering"].append(time.perf_counter() - start)
    return hair


def add_image_arguments(p) -> None:
    """--width, --height (each in [1, MAX_IMAGE_SIDE] px) and --dense (in [0, MAX_DENSE])."""
    p.add_argument("--width", type=cli_int("--width", 1, MAX_IMAGE_SIDE), default=None,
                   help="image width [px] (default: the scene's shot, else 640)")
    p.add_argument("--height", type=cli_int("--height", 1, MAX_IMAGE_SIDE), default=None,
                   help="image height [px] (default: the scene's shot, else 480)")
    p.add_argument("--dense", type=cli_int("--dense", 0, MAX_DENSE), default=None,
                   help="dense strands, 0 draws the guides (default: the scene's shot)")


def shot_overrides(args) -> dict:
    """The Shot fields the command line sets (--width, --height, --dense, --masks)."""
    overrides = {k: v for k, v in (("width", args.width), ("height", args.height),
                                   ("dense_strands", args.dense)) if v is not None}
    if getattr(args, "masks", False):
        overrides["masks"] = True
    return overrides
