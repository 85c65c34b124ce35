"""`taichi-hair bench --cosseratbench`: cosseratbench's experiments run for taichi_hair's solvers
(the adapter: taichi_hair.app.cosseratbench_plugin) and the others installed, side by side in
one table. Needs the `bench` extra: importing this module without cosseratbench raises
ModuleNotFoundError, which the bench command turns into an install hint."""

from cosseratbench import registry, runs

COMPARED = ("taichi_hair", "taichi_hair_shake", "taichi_hair_stretch", "taichi_hair_implicit", "pyelastica",
            "mujoco")


def compare(experiments=(), solvers=COMPARED, *, n_elements=None, out="out/cosseratbench",
            jobs=1, force=False, report=print) -> str:
    """Run cosseratbench's `experiments` (default: all) for `solvers` with cosseratbench's own
    runner (results saved under `out` and reused while still valid), and return one table of
    every metric, observation and wall time. Solvers that are not installed get a row saying
    so: `pip install "cosseratbench[pyelastica,mujoco]"` adds the comparison columns."""
    import json
    from pathlib import Path

    out = Path(out)
    names = list(experiments) or registry.names(registry.EXPERIMENTS)
    loaded = [registry.load_experiment(name) for name in names]
    missing = {}

    def note(line):  # plan() reports skipped runs: saved ones, and solvers not installed
        if line.rstrip().endswith(")") and "not installed" in line:
            parts = line.split()
            missing[(parts[0], parts[2])] = line[line.index("not installed"):]
        report(line)

    tasks = runs.plan(loaded, list(solvers), [], n_elements, out, force=force, report=note)
    runs.execute(tasks, jobs=jobs, report=report)
    blocks = []
    for experiment in loaded:
        summaries = {}
        for solver in solvers:
            path = out / experiment.name / "default" / solver / "result.json"
            if path.exists():
                summaries[solver] = json.loads(path.read_text())
        metric_names = list(experiment.metrics)
        observation_names = ["max_strain", "max_penetration", "max_rod_overlap"]
        header = (f"{'solver':20s} {'outcome':11s} {'n':>4s} {'wall [s]':>9s} "
                  + " ".join(f"{m:>22s}" for m in metric_names + observation_names))
        lines = [f"{experiment.name}: {experiment.description}", header]
        for solver in solvers:
            summary = summaries.get(solver)
            if summary is None:
                why = missing.get((experiment.name, solver), "not run")
                lines.append(f"{solver:20s} {why}")
                continue
            wall = summary["wall_time"]
            row = (f"{solver:20s} {summary['outcome']:11s} {summary['n_elements']:4d} "
                   + (f"{wall:9.2f} " if wall is not None else f"{'-':>9s} "))
            if summary["outcome"] == "completed":
                values = [summary["metrics"].get(m) for m in metric_names]
                values += [summary["observations"].get(o) for o in observation_names]
                row += " ".join(f"{v:22.3e}" if v is not None else f"{'n/a':>22s}" for v in values)
            elif summary["outcome"] == "unsupported":
                row += "needs " + ", ".join(summary["missing"])
            else:
                row += f"{summary['failure']} (t = {summary.get('diverged_at')})"
            lines.append(row)
        blocks.append("\n".join(lines))
    if missing:
        blocks.append('solvers not installed: pip install "cosseratbench[pyelastica,mujoco]" '
                      '"mujoco<4" for the comparison columns (MuJoCo 4 dropped the composite '
                      "cable cosseratbench 0.3 builds)")
    return "\n\n".join(blocks)


def bench_main(args) -> int:
    """`taichi-hair bench --cosseratbench`: the side-by-side table (see `compare`)."""
    experiments = [e for e in (args.experiments or "").split(",") if e]
    solvers = [s for s in args.solvers.split(",") if s]
    print(compare(experiments, solvers, n_elements=args.n_elements, out=args.out,
                  jobs=args.jobs, force=args.force))
    return 0
