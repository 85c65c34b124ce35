"""Kmoch's loop, one time step h: forces, integrate, project (inextensibility + contacts),
velocities, frames, twist. Read in this order:

- `stages.py`: the per-strand stages of one step, in order (`STAGES`): the page to read first.
- `projection.py`: the projection stage (inextensibility alternating with collider pushes).
- `plan.py`: which stages run (`StepPlan` from the solver's options, the compile-time
  `StageFlags` of a launch) and the thresholds that judge a step.
- `bundles.py`: the kernels' arguments as bundles of arrays, and the launch's scalars.
- `fused.py`, `implicit_launches.py`, `contact.py`: the kernels that run the stages: many steps
  per launch with one thread per strand (`advance_strands`), the stages in launches of their
  own (`run_stages`: per-stage timings, hair-hair interaction), the implicit step's integration
  in kernels of its own, and steps with strand-strand contact.
- `launch.py`: the drivers' entry points (`advance`, `staged_step`, `project_once`);
  solver/drivers.py chooses among them once per simulator.

Stages a scene does not use are removed at compile time (`ti.static` flags), so they are neither
compiled nor run. Python's per-launch cost (about 12-20 us per array argument with Taichi 1.7)
would dominate small scenes with a launch per stage, hence the fused default.

Head poses: `head[k]` ([K+1, 4] vec3: rows of R, then t) is the head before step 0 (k = 0) and
after step k-1; a static head passes [prev, now] and uses now for every step after the first.
"""
