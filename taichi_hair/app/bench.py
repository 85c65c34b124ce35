"""`taichi-hair bench`: simulation throughput on a reference scene (below).

Scene: S guides x 32 nodes of human hair (E = 3 GPa, G = 1 GPa, radius 40 um, 1 cm segments,
rho = 1300 kg/m^3), roots spread over a 10 cm sphere and growing outward, gravity on, no drag,
dt = 1 ms, twist "quasistatic" (the default), each integrator asked for (explicit: substepped to
its bound; implicit: one step). One simulated frame is 1/60 s (17 steps). Every number is a median
of repeated runs after a warm-up; compile time (the first call) is reported apart.
"""

import json
import statistics
import subprocess
import sys
import time
from contextlib import contextmanager

import numpy as np

from ..validation import cli_int, cli_int_list

FRAME = 1.0 / 60.0
NODES = 32
SEGMENT = 0.01


def bench_groom(n_strands: int):
    """Straight guides on a Fibonacci sphere of radius 10 cm (upper part), growing outward."""
    from ..rods.groom import Groom
    k = np.arange(n_strands) + 0.5
    z = 1.0 - 0.8 * k / n_strands  # polar caps only: hair grows on the top of the head
    phi = np.pi * (1 + 5**0.5) * k
    r = np.sqrt(1 - z * z)
    normals = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    return Groom.straight(roots=0.1 * normals, directions=normals, length=SEGMENT * (NODES - 1),
                          n_nodes=NODES)


def _median_ms(samples):
    return 1e3 * statistics.median(samples)


def bench_case(n_strands: int, repeats: int, stage_steps: int, twist: str = "quasistatic",
               integrator: str = "explicit") -> dict:
    """Time one strand count in this process (Taichi already initialised)."""
    from ..rods.materials import Material
    from ..solver.simulator import Simulator

    groom = bench_groom(n_strands)
    material = Material(youngs_modulus=3e9, shear_modulus=1e9, radius=40e-6, density=1300.0)
    sim = Simulator(groom, material, dt=1e-3, twist=twist, integrator=integrator)
    steps = int(round(FRAME / sim.dt))
    compile_s, frame_ms = _time_frames(sim, repeats)
    stages = stage_breakdown(sim, stage_steps)
    return {
        "strands": n_strands, "integrator": integrator, "nodes": NODES, "steps_per_frame": steps,
        "substeps": sim.substeps,
        "compile_s": compile_s, "ms_per_frame": frame_ms,
        "strand_node_steps_per_s": n_strands * NODES * steps / (frame_ms / 1e3),
        "stage_ms_per_step": stages,
    }


def stage_breakdown(sim, n_steps: int) -> dict:
    """Median ms per step of each stage, run as separate synchronised kernels."""
    import taichi as ti
    times: dict[str, list] = {}

    @contextmanager
    def timer(name):
        ti.sync()
        start = time.perf_counter()
        yield
        ti.sync()
        times.setdefault(name, [0.0] * n_steps)[current[0]] += time.perf_counter() - start

    current = [0]
    sim.step(1, timers=timer)  # warm-up: compiles the per-stage kernels
    times.clear()
    for k in range(n_steps):
        current[0] = k
        sim.step(1, timers=timer)
    return {name: _median_ms(values) / sim.substeps for name, values in times.items()}


def _time_frames(sim, repeats):
    """(compile + first frame [s], median ms per 1/60 s frame) of a built simulator. The warm-up
    is a whole frame: a moving head steps a frame with one head pose per step, another kernel
    variant than a single step's, and timing its compile as a frame read 99.7 s per frame."""
    import taichi as ti
    steps = int(round(FRAME / sim.dt))
    start = time.perf_counter()
    sim.step(steps)
    ti.sync()
    compile_s = time.perf_counter() - start
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        sim.step(steps)
        ti.sync()
        samples.append(time.perf_counter() - start)
    return compile_s, _median_ms(samples)


def bench_full_head(n_guides: int, repeats: int, integrators=("explicit",)) -> dict:
    """The project's head (mesh collider + neck/shoulder capsules) with n_guides x 32 nodes from
    its scalp, shaking: straight human hair with and without grid hair-hair interaction, and
    curly elliptic hair (shake_curly's: curl radius 8 mm, pitch 3 cm, ellipticity 1.5, radius
    45 um, 22 cm) without it, whose tight curls set the explicit step's substeps."""
    from ..world.forces import HairInteraction
    from ..rods.materials import Material
    from ..world.motion import Shake
    from ..hair.roots import scalp_groom
    from ..world.scene import Head, Scene
    from ..solver.simulator import Simulator
    head = Head.default()
    grid = head.colliders[0].grid
    straight = scalp_groom(head.model, n_guides, style="straight", length=SEGMENT * (NODES - 1),
                           n_nodes=NODES, collider=grid, seed=0)
    curly = scalp_groom(head.model, n_guides, style="curly", length=0.22, n_nodes=NODES, curl_radius=0.008,
                        curl_pitch=0.03, collider=grid, seed=0)
    curly_material = Material(youngs_modulus=3e9, shear_modulus=1e9, radius=45e-6, ellipticity=1.5)
    hairs = [("straight", straight, Material(), None), ("straight", straight, Material(), HairInteraction()),
             ("curly", curly, curly_material, None)]
    rows = []
    for integrator in integrators:
        for style, groom, material, interaction in hairs:
            scene = Scene(groom=groom, head=head, material=material, motion=Shake(amplitude_deg=30, frequency_hz=1),
                          hair_interaction=interaction, integrator=integrator)
            sim = Simulator.from_scene(scene, dt=1e-3)
            compile_s, frame_ms = _time_frames(sim, repeats)
            rows.append({"guides": n_guides, "integrator": integrator, "style": style,
                         "hair_interaction": interaction is not None,
                         "substeps": sim.substeps, "compile_s": compile_s, "ms_per_frame": frame_ms,
                         "strand_node_steps_per_s": n_guides * NODES * round(FRAME / sim.dt) / (frame_ms / 1e3)})
    return {"scene": "default head mesh + capsules, shake 30 deg at 1 Hz, dt 1 ms; straight combed human hair "
                     "(hair-hair off / on) and curly elliptic hair (curl radius 8 mm, ellipticity 1.5)",
            "rows": rows}


def run_bench(arch: str, precision: str, strands, repeats: int, stage_steps: int, twist: str,
              head_guides: int = 0, dense: int = 0, integrators=("explicit",)) -> dict:
    from ..runtime import init
    init(arch=arch, precision=precision)
    result = {"arch": arch, "precision": precision, "dt": 1e-3, "frame_s": FRAME, "twist": twist,
              "scene": "human hair: E 3 GPa, G 1 GPa, r 40 um, rho 1300, 32 nodes, 1 cm segments, "
                       "gravity on, no drag",
              "cases": [bench_case(n, repeats, stage_steps, twist, integrator)
                        for integrator in integrators for n in strands]}
    if head_guides:
        result["full_head"] = bench_full_head(head_guides, max(1, repeats // 2), integrators)
    if dense:
        from ..hair.interpolate import bench_interpolation
        result["interpolation"] = bench_interpolation(n_dense=dense, n_nodes=NODES, n_guides=1000,
                                                      repeats=repeats)
    return result


def format_table(result: dict) -> str:
    from ..solver.step.stages import STAGE_NAMES
    stage_names = list(STAGE_NAMES)
    lines = [f"taichi_hair bench: arch {result['arch']}, precision {result['precision']}, "
             f"dt {result['dt'] * 1e3:g} ms, frame 1/60 s, twist {result['twist']}",
             f"scene: {result['scene']}",
             f"{'strands':>8} {'integrator':>10} {'substeps':>8} {'compile s':>9} {'ms/frame':>10} "
             f"{'node-steps/s':>13} | per step, ms: "
             + " ".join(f"{n:>14}" for n in stage_names)]
    for c in result["cases"]:
        stage = " ".join(f"{c['stage_ms_per_step'].get(n, 0.0):14.3f}" for n in stage_names)
        lines.append(f"{c['strands']:8d} {c.get('integrator', 'explicit'):>10} {c['substeps']:8d} "
                     f"{c['compile_s']:9.2f} {c['ms_per_frame']:10.2f} "
                     f"{c['strand_node_steps_per_s']:13.3e} | {'':13} {stage}")
    lines.append("ms/frame: fused launch (all stages in one kernel per frame), median; stage columns: "
                 "one synchronised kernel per stage, median per step (includes launch overhead)")
    if "full_head" in result:
        head = result["full_head"]
        lines.append(f"full head: {head['scene']}")
        for row in head["rows"]:
            lines.append(f"{row['guides']:8d} guides, {row.get('style', 'straight'):8}, "
                         f"{row.get('integrator', 'explicit')}, "
                         f"hair-hair {'on ' if row['hair_interaction'] else 'off'}: "
                         f"{row['ms_per_frame']:10.1f} ms/frame  {row['strand_node_steps_per_s']:.3e} node-steps/s"
                         f"  ({row['substeps']} substeps, compile {row['compile_s']:.1f} s)")
    if "interpolation" in result:
        dense = result["interpolation"]
        lines.append("dense hair interpolation: " + ", ".join(
            f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in dense.items()))
    return "\n".join(lines)


def main(args) -> int:
    if args.cosseratbench:  # optional extra: imported only when asked for
        try:
            from .cosseratbench_compare import bench_main
        except ModuleNotFoundError as err:
            raise ValueError(f"--cosseratbench needs the bench extra ({err.name} is missing): "
                             f"pip install 'taichi_hair[bench]'") from None
        return bench_main(args)
    if args.compile:
        return compile_main(args)
    apply_preset(args)
    scene = None
    if args.scene is not None:
        if args.against is None:
            raise ValueError("--scene compares a scene's run against an older commit: give --against REV too")
        from .history import check_scene
        scene = check_scene(args.scene)
    strands = args.strands if isinstance(args.strands, list) else [int(s) for s in args.strands.split(",")]
    if args.against is not None:
        from .history import bench_args_of, compare, format_comparison
        args.strands = strands
        result = compare(args.against, bench_args_of(args), args.rounds,
                         progress=lambda line: print(line, file=sys.stderr, flush=True),
                         scene=scene, frames=args.frames)
        print(json.dumps(result, indent=2) if args.json else format_comparison(result))
        return 0
    integrators = ("explicit", "implicit") if args.integrator == "both" else (args.integrator,)
    precisions = ["float32", "float64"] if args.precision == "both" else [args.precision]
    results = []
    for precision in precisions:
        if len(precisions) == 1:
            results.append(run_bench(args.arch, precision, strands, args.repeats, args.stage_steps,
                                     args.twist, args.head_guides, args.dense, integrators))
            continue
        # one precision per process: Taichi cannot change it after init
        cmd = [sys.executable, "-m", "taichi_hair", "bench", "--json", "--arch", args.arch,
               "--precision", precision, "--strands", ",".join(map(str, strands)), "--repeats", str(args.repeats),
               "--stage-steps", str(args.stage_steps), "--twist", args.twist,
               "--head-guides", str(args.head_guides), "--dense", str(args.dense),
               "--integrator", args.integrator]
        out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
        results.extend(json.loads(out[out.index("[\n"):]))  # skip Taichi's banner line
    if args.json:
        print(json.dumps(results, indent=2))
    else:
        print("\n\n".join(format_table(r) for r in results))
    return 0


def compile_main(args) -> int:
    """`bench --compile`: the cold first-frame compile table (app/compiletime.py)."""
    from .compiletime import compile_table, format_cells, shipped_scenes
    scenes = shipped_scenes()
    if args.scenes:
        known = {p.stem: p for p in scenes}
        wanted = [name.strip() for name in args.scenes.split(",") if name.strip()]
        unknown = [name for name in wanted if name not in known]
        if unknown or not wanted:
            raise ValueError(f"--scenes must name shipped scenes ({', '.join(sorted(known))}), got {args.scenes!r}")
        scenes = [known[name] for name in wanted]
    integrators = ("explicit", "implicit") if args.integrator in (None, "both") else (args.integrator,)
    cells = compile_table(scenes, integrators, args.compile_timeout,
                          progress=lambda line: print(line, file=sys.stderr, flush=True))
    print(json.dumps(cells, indent=2) if args.json else format_cells(cells, kernels=args.kernels))
    return 0 if all("error" not in c for c in cells) else 1


# the table's size: the quick one by default (a couple of minutes on 2 cores, the implicit
# step's long first compile left out), --full for the whole table; an option given wins
QUICK = {"strands": "1,100,1000", "repeats": 3, "stage_steps": 3, "integrator": "explicit", "head_guides": 200,
         "dense": 20_000}
FULL = {"strands": "1,100,1000,10000", "repeats": 5, "stage_steps": 5, "integrator": "both", "head_guides": 1000,
        "dense": 100_000}


def apply_preset(args) -> None:
    """Fill the table options not given on the command line from QUICK, or FULL with --full."""
    for name, value in (FULL if args.full else QUICK).items():
        if getattr(args, name) is None:
            setattr(args, name, value)


def _preset(name) -> str:
    return f"default: {QUICK[name]}, with --full {FULL[name]}"


def add_parser(sub):
    p = sub.add_parser("bench", help="simulation throughput table (strand-node-steps/s, ms per frame); "
                                     "quick by default, --full for the whole table")
    p.add_argument("--full", action="store_true",
                   help="the whole table: 10000 guides, both integrators (the implicit step compiles for "
                        "minutes on a cold cache), 1000 head guides, 100000 dense strands")
    p.add_argument("--compile", action="store_true",
                   help="instead: the cold compile time of every shipped scene's first frame, each integrator, "
                        "each cell in a subprocess with a fresh Taichi offline cache (minutes per cell)")
    p.add_argument("--scenes", default=None,
                   help="with --compile: comma-separated scene names (default: every script in scenes/)")
    p.add_argument("--kernels", action="store_true",
                   help="with --compile: each cell's kernels under it, front and back end compile times")
    p.add_argument("--compile-timeout", type=cli_int("--compile-timeout", 10, 100_000), default=1800,
                   help="with --compile: seconds a cell may run before it is reported as over (default: 1800)")
    p.add_argument("--arch", default="cpu", help="cpu, or cuda where a GPU exists")
    p.add_argument("--precision", default="float32", choices=["float32", "float64", "both"], help="float type")
    p.add_argument("--strands", type=cli_int_list("--strands", 1, 1_000_000), default=None,
                   help=f"comma-separated guide counts ({_preset('strands')})")
    p.add_argument("--repeats", type=cli_int("--repeats", 1, 1000), default=None,
                   help=f"timed frames per case, median ({_preset('repeats')})")
    p.add_argument("--stage-steps", type=cli_int("--stage-steps", 1, 10_000), default=None,
                   help=f"steps timed stage by stage ({_preset('stage_steps')})")
    p.add_argument("--twist", default="quasistatic", choices=["kmoch", "quasistatic", "none"], help="twist update")
    p.add_argument("--integrator", default=None, choices=["explicit", "implicit", "both"],
                   help=f"rows for each integrator ({_preset('integrator')})")
    p.add_argument("--head-guides", type=cli_int("--head-guides", 0, 100_000), default=None,
                   help="guides on the full-head row (head collision, with and without hair-hair); 0 skips it "
                        f"({_preset('head_guides')})")
    p.add_argument("--dense", type=cli_int("--dense", 0, 10_000_000), default=None,
                   help="dense strands interpolated per frame on the interpolation row; 0 skips it "
                        f"({_preset('dense')})")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--against", default=None, metavar="REV",
                   help="also run the same table from commit REV (a temporary git worktree), alternating "
                        "round by round, and print both with their ratio (default: this tree alone)")
    p.add_argument("--rounds", type=cli_int("--rounds", 1, 100), default=3,
                   help="alternating rounds of each tree with --against (medians over them)")
    p.add_argument("--scene", default=None, metavar="SCRIPT",
                   help="with --against: time this scene's run (taichi-hair run SCRIPT --frames N) in both trees "
                        "instead of the table, e.g. the main job scenes/wind_straight.py: wall time and the "
                        "median simulation / interpolation / rendering ms per frame (default: the table)")
    p.add_argument("--frames", type=cli_int("--frames", 1, 100_000), default=24,
                   help="with --scene: frames per run (default: 24)")
    cb = p.add_argument_group("cosseratbench (pip install taichi_hair[bench]; for the comparison "
                              "columns also pip install \"cosseratbench[pyelastica,mujoco]\" "
                              "\"mujoco<4\")")
    cb.add_argument("--cosseratbench", action="store_true",
                    help="run cosseratbench's scenarios for taichi_hair and the other solvers side by "
                         "side and print every metric and wall time in one table (float64)")
    cb.add_argument("--experiments", default="", help="comma-separated experiments (default: all)")
    cb.add_argument("--solvers",
                    default="taichi_hair,taichi_hair_shake,taichi_hair_stretch,taichi_hair_implicit,pyelastica,mujoco",
                    help="comma-separated cosseratbench solvers")
    cb.add_argument("--n-elements", type=cli_int("--n-elements", 2, 100_000), default=None,
                    help="elements per rod (default: each experiment's)")
    cb.add_argument("--out", default="out/cosseratbench",
                    help="results directory (saved runs are reused while still valid)")
    cb.add_argument("--jobs", type=cli_int("--jobs", 1, 256), default=1, help="runs at once (wall times read high above 1)")
    cb.add_argument("--force", action="store_true", help="rerun saved runs")
    p.set_defaults(func=main)
