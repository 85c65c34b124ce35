"""`taichi-hair` command line (also `python -m taichi_hair`)."""

import argparse
import sys

import numpy as np

from . import bench
from . import doctor
from . import inverse
from . import reports
from . import run_command
from . import sweep
from ..solver.stability import SimulationDiverged
from ..validation import cli_int, cli_real, one_line_parser_class


def _demo(args) -> int:
    """Build a curly strand, bend it, solve its twist and print energy and forces."""
    import taichi_hair as th

    th.init(arch=args.arch, precision=args.precision)
    groom = th.Groom.curly(length=args.length, n_nodes=args.nodes, curl_radius=args.curl_radius,
                           curl_pitch=args.curl_pitch)
    material = th.Material(ellipticity=args.ellipticity)
    sim = th.Simulator(groom, material, twist=args.twist)
    x = sim.positions()
    # bend: swing every node about the root by an angle growing linearly to args.bend at the tip
    depth = np.linalg.norm(x[0] - x[0, 0], axis=1)
    angle = np.radians(args.bend) * depth / depth.max()
    rel = x[0] - x[0, 0]
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    bent = x.copy()
    bent[0, :, 0] = x[0, 0, 0] + (c[:, 0] * rel[:, 0] - s[:, 0] * rel[:, 2])
    bent[0, :, 2] = x[0, 0, 2] + (s[:, 0] * rel[:, 0] + c[:, 0] * rel[:, 2])
    bent[0, 0] = x[0, 0]  # the root node rides on the head
    sim.set_positions(bent)
    report = sim.update_twist()
    forces = sim.elastic_forces()[0]
    print(f"curly strand: {args.nodes} nodes, length {groom.lengths()[0] * 100:.1f} cm, "
          f"curl radius {args.curl_radius * 1000:.1f} mm, pitch {args.curl_pitch * 1000:.1f} mm, "
          f"ellipticity {args.ellipticity}, E {material.youngs_modulus:.3g} Pa, "
          f"radius {material.radius * 1e6:.0f} um ({th.runtime.precision()}, {args.arch})")
    print(f"bent by up to {args.bend:.0f} degrees at the tip; twist '{args.twist}': {report}")
    print(f"elastic energy: {sim.elastic_energy():.6e} J")
    print(f"{'node':>4} {'Fx [N]':>12} {'Fy [N]':>12} {'Fz [N]':>12} {'|F| [N]':>12}")
    for i, f in enumerate(forces):
        print(f"{i:4d} {f[0]:12.4e} {f[1]:12.4e} {f[2]:12.4e} {np.linalg.norm(f):12.4e}")
    print(f"net force on the free nodes (balanced by the clamped root): {forces[1:].sum(axis=0)}")
    return 0


class DefaultsHelpFormatter(argparse.HelpFormatter):
    """Every option's help ends with its default ("(default: X)"), unless the help already says
    it; flags (no value) are off unless given."""

    def _get_help_string(self, action):
        text = action.help or ""
        if (not action.option_strings or action.nargs == 0 or action.required
                or action.default is argparse.SUPPRESS):
            return text
        if "default" in text:
            return text
        return f"{text} (default: %(default)s)".lstrip()


class Parser(one_line_parser_class()):
    """argparse's parser with one-line errors and DefaultsHelpFormatter, for every subcommand too."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", DefaultsHelpFormatter)
        super().__init__(*args, **kwargs)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="taichi-hair", description=__doc__)
    parser.add_argument("--debug", action="store_true",
                        help="show the traceback of an error (accepted anywhere on the line)")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser)
    demo = sub.add_parser("demo", help="bend a curly strand and print its energy and forces")
    demo.add_argument("--arch", default="cpu", help="Taichi arch: cpu, cuda, gpu, vulkan or metal")
    demo.add_argument("--precision", default="float64", choices=["float32", "float64"], help="float type")
    demo.add_argument("--nodes", type=cli_int("--nodes", 3, 10_000), default=16, help="nodes of the strand")
    demo.add_argument("--length", type=cli_real("--length", 0.0, 10.0, unit="m"), default=0.15,
                      help="strand length [m]")
    demo.add_argument("--curl-radius", type=cli_real("--curl-radius", 0.0, 1.0, unit="m"), default=0.01,
                      help="helix radius [m]")
    demo.add_argument("--curl-pitch", type=cli_real("--curl-pitch", 0.0, 1.0, low_open=False, unit="m"),
                      default=0.02, help="helix pitch [m per turn]")
    demo.add_argument("--ellipticity", type=cli_real("--ellipticity", 1.0, 10.0, low_open=False), default=1.5,
                      help="cross-section ellipticity (1: round)")
    demo.add_argument("--bend", type=cli_real("--bend", -360.0, 360.0, low_open=False, unit="degrees"),
                      default=30.0, help="bend at the tip [degrees]")
    demo.add_argument("--twist", default="quasistatic", choices=["kmoch", "quasistatic", "none"],
                      help="twist update")
    demo.set_defaults(func=_demo)
    doctor.add_parser(sub)
    bench.add_parser(sub)
    run_command.add_parser(sub)
    sweep.add_parser(sub)
    inverse.add_parser(sub)
    reports.add_parsers(sub)
    return parser


def main(argv=None) -> int:
    """Run a command. A user error (bad input: ValueError, HairFileError; a file the system
    refuses: OSError; a scene that diverges: SimulationDiverged) prints one line naming the file
    or parameter and exits with 2; `--debug` (anywhere on the line) shows the traceback instead."""
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    args = build_parser().parse_args([a for a in argv if a != "--debug"])
    try:
        return args.func(args)
    except (ValueError, OSError, SimulationDiverged) as err:
        if debug:
            raise
        print(f"taichi-hair: error: {_one_line(err)} (--debug shows the traceback)", file=sys.stderr)
        return 2


def _one_line(err) -> str:
    """The error as one line; an OSError names its file."""
    if isinstance(err, OSError) and err.filename is not None:
        text = f"{err.filename}: {err.strerror or err}"
    else:
        text = str(err) or type(err).__name__
    return " ".join(text.split())


if __name__ == "__main__":
    sys.exit(main())
