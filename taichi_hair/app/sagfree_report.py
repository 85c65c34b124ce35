"""`taichi-hair report sagfree`: the drift experiment. A mixed groom on the default head,
simulated under gravity with and without the sag-free start (hair/sagfree.py), and how far its
nodes drift from where they were groomed."""

import math
import time

import numpy as np

from ..hair.roots import scalp_groom
from ..hair.sagfree import sag_free
from ..rods.groom import Groom
from ..rods.materials import Material
from ..solver.simulator import Simulator
from ..world.scene import Head, Scene


def mixed_head_groom(n_guides: int = 200, n_nodes: int = 32, seed: int = 0):
    """(Head.default(), Groom): n_guides guides on the default head, a third each straight,
    wavy and curly, lengths 10-40 cm (0.25 m +- 60 %), combed back and groomed around the head."""
    head = Head.default()
    field = head.distance_field()
    counts = [n_guides // 3 + (k < n_guides % 3) for k in range(3)]
    strands = []
    for k, (style, count) in enumerate(zip(("straight", "wavy", "curly"), counts)):
        if count:
            part = scalp_groom(head.model, count, style=style, length=0.25, length_variation=0.6,
                               n_nodes=n_nodes, collider=field, seed=seed + k)
            strands += [part.strand(s) for s in range(part.n_strands)]
    return head, Groom.from_polylines(strands)


def drift_experiment(n_guides: int = 200, seconds: float = 5.0, drag: float = 3e-4,
                     n_nodes: int = 32, dt: float = 1e-3, progress: bool = False) -> dict:
    """Simulate `mixed_head_groom` for `seconds` under gravity with `drag` [N s/m per m], with
    and without the sag-free start; node drift [m] from the groomed positions (all nodes, in
    head coordinates: the head does not move) and the solve's cost. Twist "none" (the robust
    choice for sag-free round hair, see `sag_free`); rest turning angles up to 160 degrees."""
    head, groom = mixed_head_groom(n_guides, n_nodes)
    material = Material()
    fixed, report = sag_free(groom, material, head=head, twist="none", max_turning_deg=160.0)
    held_strands = report.solved & ~report.fell_back & ~report.clipped
    rows = {}
    for label, start in (("groomed rest shape", groom), ("sag-free rest shape", fixed)):
        sim = Simulator.from_scene(Scene(groom=start, head=head, material=material, drag=drag,
                                         twist="none"), dt=dt)
        start_x = sim.positions()  # after initial contacts are resolved
        began = time.perf_counter()
        sim.run(seconds, progress=progress)
        wall = time.perf_counter() - began
        drift = np.linalg.norm(sim.positions() - groom.positions, axis=2)
        mask = np.arange(groom.max_nodes)[None, :] < groom.node_counts[:, None]
        held = mask & held_strands[:, None]
        rows[label] = {"mean_drift_m": float(drift[mask].mean()), "max_drift_m": float(drift[mask].max()),
                       "held_mean_drift_m": float(drift[held].mean()) if held.any() else math.nan,
                       "held_max_drift_m": float(drift[held].max()) if held.any() else math.nan,
                       "start_offset_m": float(np.linalg.norm(start_x - groom.positions, axis=2)[mask].max()),
                       "wall_s": wall, "substeps": sim.substeps}
    return {"n_guides": groom.n_strands, "n_held": int(held_strands.sum()),
            "n_nodes": n_nodes, "seconds": seconds, "drag": drag, "dt": dt,
            "solve_s": report.seconds, "solve_ms_per_guide": 1e3 * report.seconds / groom.n_strands,
            "summary": report.summary(), "unreachable": report.n_unreachable, "rows": rows}


def report_main(args) -> int:
    """`taichi-hair report sagfree`: the drift table."""
    from .. import runtime
    runtime.init(precision=args.precision, arch=args.arch)
    guides, seconds = (30, 1.0) if args.quick else (args.guides, args.seconds)
    result = drift_experiment(guides, seconds, args.drag, progress=not args.quick)
    print(result["summary"])
    print(f"\n{result['n_guides']} guides x {result['n_nodes']} nodes on the default head, "
          f"{seconds:g} s under gravity, drag {args.drag:g}, dt {result['dt']:g} s ({args.precision})")
    print(f"{'':<22}{'all strands':>32}{'the ' + str(result['n_held']) + ' held':>32}")
    print(f"{'start':<22}{'mean drift [mm]':>16}{'max drift [mm]':>16}{'mean drift [mm]':>16}"
          f"{'max drift [mm]':>16}{'sim wall [s]':>14}")
    for label, row in result["rows"].items():
        print(f"{label:<22}{1e3 * row['mean_drift_m']:>16.3f}{1e3 * row['max_drift_m']:>16.3f}"
              f"{1e3 * row['held_mean_drift_m']:>16.3f}{1e3 * row['held_max_drift_m']:>16.3f}"
              f"{row['wall_s']:>14.1f}")
    print("held: strands whose sag-free balance is a minimum (the others keep the groomed rest "
          "shape: their balance is a saddle, see th.sag_free)")
    print(f"solve: {result['solve_s']:.2f} s ({result['solve_ms_per_guide']:.1f} ms per guide)")
    return 0


def add_report_parser(sub) -> None:
    """`report sagfree` on an argparse subparsers object."""
    from ..validation import cli_int, cli_real
    p = sub.add_parser("sagfree", help="node drift under gravity with and without the sag-free start")
    p.add_argument("--quick", action="store_true", help="30 guides, 1 s")
    p.add_argument("--guides", type=cli_int("--guides", 1, 100_000), default=200)
    p.add_argument("--seconds", type=cli_real("--seconds", 0.0, 1000.0, unit="s"), default=5.0)
    p.add_argument("--drag", type=cli_real("--drag", 0.0, 1.0, low_open=False, unit="N s/m per m"), default=3e-4,
                   help="air drag [N s/m per m of strand]")
    p.add_argument("--precision", default="float64", choices=["float32", "float64"],
                   help="float64 (default): in float32 the position-based velocities of the tiny "
                        "substeps a scalp groom needs random-walk weakly held strands by millimetres")
    p.add_argument("--arch", default="cpu")
    p.set_defaults(func=report_main)
