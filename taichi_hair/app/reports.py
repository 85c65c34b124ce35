"""`taichi-hair report ...`: the validation reports' command line.

  accuracy   error against run time on independent references (app/accuracy_report.py)
  stability  the stability matrix: stable / substepped / refused / FAIL (app/stability_report.py)
  implicit   the implicit step against the explicit one (app/implicit_report.py)
  sagfree    node drift with and without the sag-free start (hair/sagfree.py)
  markdown   docs/validation.md from the reports' JSON (app/validation_page.py)

Each report writes <name>.json (stamped: commit, date, machine, settings) to --out (out/reports).
`python -m taichi_hair.app.reports KIND --worker` is the subprocess a report runs its rows of
the other precision in (app/report_dispatch.py).
"""

import argparse
import json
import sys

from .. import runtime
from .sagfree_report import add_report_parser as add_sagfree_parser
from ..validation import cli_real, one_line_parser_class
from ..world.scene import PROJECTIONS
from . import cluster
from . import implicit_report
from . import validation_page
from .accuracy_report import AccuracySweep, accuracy_report, accuracy_rows, format_accuracy, helix_reference
from .report_dispatch import cluster_client, log_line, worker_answer
from .stability_cases import StabilityCase
from .stability_report import format_stability, stability_report, stability_rows


def _accuracy_main(args) -> int:
    if args.worker:
        runtime.init(arch=args.arch, precision=args.precision)
        if args.specs:
            worker_answer({"rows": accuracy_rows(None, log_line, json.loads(args.specs))})
            return 0
        sweep = AccuracySweep(**{k: tuple(v) if isinstance(v, list) else v for k, v in json.loads(args.sweep).items()})
        worker_answer({"rows": accuracy_rows(sweep, log_line) if not args.no_rows else [],
                       "reference": helix_reference(sweep) if args.reference else None})
        return 0
    precisions = ["float32", "float64"] if args.precision == "both" else [args.precision]
    with cluster_client(args) as client:
        result = accuracy_report(args.quick, precisions, args.out, arch=args.arch, log=log_line, client=client)
    print(json.dumps(result, indent=1) if args.json else format_accuracy(result))
    return 0


def _stability_main(args) -> int:
    if args.worker:
        runtime.init(arch=args.arch, precision=args.precision)
        cases = [StabilityCase(**c) for c in json.loads(sys.stdin.read())]
        worker_answer(stability_rows(cases, args.duration, log_line))
        return 0
    with cluster_client(args) as client:
        result = stability_report(args.quick, args.out, log=log_line, precision=args.precision, arch=args.arch,
                                  duration=args.duration, client=client, integrator=args.integrator,
                                  projection=args.projection)
    print(json.dumps(result, indent=1) if args.json else format_stability(result))
    return 1 if result["failures"] else 0


def _markdown_main(args) -> int:
    path = validation_page.write_page(args.reports, args.out)
    print(f"written: {path}")
    return 0


def _add_commands(sub):
    acc = sub.add_parser("accuracy", help="error against run time (table, JSON and a log-log PNG)")
    acc.add_argument("--quick", action="store_true", help="smaller sweep (about a minute)")
    acc.add_argument("--precision", default="both", choices=["float32", "float64", "both"])
    acc.add_argument("--out", default="out/reports", help="folder for accuracy.json and accuracy.png")
    acc.add_argument("--arch", default="cpu")
    acc.add_argument("--json", action="store_true", help="print JSON instead of the table")
    acc.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    acc.add_argument("--sweep", help=argparse.SUPPRESS)
    acc.add_argument("--no-rows", action="store_true", help=argparse.SUPPRESS)
    acc.add_argument("--reference", action="store_true", help=argparse.SUPPRESS)
    acc.add_argument("--specs", help=argparse.SUPPRESS)
    cluster.add_arguments(acc)
    acc.set_defaults(func=_accuracy_main)
    stab = sub.add_parser("stability", help="the stability matrix: stable / substepped / refused / FAIL per case "
                                            "(exit 1 on any FAIL)")
    stab.add_argument("--quick", action="store_true", help="a third of the cases (every axis), 0.1 s simulated each")
    stab.add_argument("--precision", default="both", choices=["both", "float32", "float64"],
                      help="both: each case in its own precision (one process each); else every case in this one")
    stab.add_argument("--out", default="out/reports", help="folder for stability.json")
    stab.add_argument("--arch", default="cpu")
    stab.add_argument("--json", action="store_true", help="print JSON instead of the table")
    stab.add_argument("--duration", type=cli_real("--duration", 0.0, 100.0, unit="s"),
                      help="simulated seconds per case (default 0.2, quick 0.1)")
    stab.add_argument("--integrator", default=None, choices=["explicit", "implicit"],
                      help="run every case with this integrator (default: each case's own, explicit)")
    stab.add_argument("--projection", default=None, choices=PROJECTIONS,
                      help="run every case with this projection of the explicit step (default: each case's own, fast)")
    stab.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    cluster.add_arguments(stab)
    stab.set_defaults(func=_stability_main)
    add_sagfree_parser(sub)
    implicit_report.add_parser(sub)
    page = sub.add_parser("markdown", help="write docs/validation.md from the reports' JSON (accuracy.json, "
                                           "stability.json, implicit.json), stamped with each report's commit, "
                                           "date, machine and settings")
    page.add_argument("--reports", default="out/reports", help="the folder the reports wrote their JSON to")
    page.add_argument("--out", default="docs/validation.md", help="the page to write")
    page.set_defaults(func=_markdown_main)


def add_parsers(sub) -> None:
    """Add `report accuracy | stability | implicit | sagfree | markdown` to an argparse subparsers object."""
    report = sub.add_parser("report", help="validation reports: accuracy, stability, implicit, sagfree, and the "
                                           "page they make (markdown)")
    _add_commands(report.add_subparsers(dest="report", required=True))


def main(argv=None) -> int:
    parser = one_line_parser_class()(prog="python -m taichi_hair.app.reports", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_commands(parser.add_subparsers(dest="report", required=True))
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except ValueError as err:
        print(f"taichi-hair report: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
