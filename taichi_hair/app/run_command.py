"""`taichi-hair run SCENE.py --out DIR`: the command line of a run, serial (runner.run_scene) or
spread over a Dask cluster (cluster.run_scene, with --workers / --scheduler)."""

from pathlib import Path

from . import cluster
from ..validation import cli_int
from ..world.scene import PROJECTIONS, STRAIN_CHOICES
from .run_output import format_summary
from .runner import MAX_FRAMES, add_image_arguments, run_scene, shot_overrides

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
    p.add_argument("--masks", action="store_true",
                   help="also write frames/mask_NNNNN.png, each frame's hair and meshes as white on black "
                        "(what `python -m render.contact` measures the framing with)")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress bar: one line per frame on stderr (frame, simulated time, sim / "
                        "interpolation / render ms)")
    cluster.add_arguments(p)
    p.set_defaults(func=main)


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
