"""`taichi-hair inverse`: an inverse problem solved with gradients of a simulated motion
(docs/differentiable.md, "Inverse demo").

`recover_material` simulates a tight elliptic curl on a shaking head with a known Young's
modulus and air drag, then starts 3x off on both and recovers them from the node positions
alone, by BFGS (our own, below) on the logarithms of the two values with gradients from
`th.Differentiable.value_and_grad`."""

import json
import math
import time

import numpy as np

from ..diff import losses
from ..diff.problem import Differentiable
from ..rods.groom import Groom
from ..rods.materials import Material
from ..solver.stability import SimulationDiverged, stable_time_step
from ..validation import cli_int_list, cli_real

ARMIJO = 1e-4  # fraction of the predicted decrease a line-search step must deliver
FIRST_STEP = 0.5  # length of the first step in the parameters (log values: a factor e^0.5)


def minimise(value_and_grad, value, u0, *, iterations: int = 40, tolerance: float = 1e-9, log=None):
    """Minimise a smooth function of a small vector u by BFGS with a backtracking (Armijo) line
    search. value_and_grad(u) -> (f, df/du); value(u) -> f (inf where the run fails).
    Returns (u, history [(iteration, u, f, |df/du|)]); stops when an iteration changes no entry of
    u by more than `tolerance` or decreases f by less than `tolerance` of itself, or after
    `iterations`."""
    u = np.asarray(u0, dtype=np.float64)
    f, g = value_and_grad(u)
    inverse_hessian = np.eye(len(u)) * FIRST_STEP / max(np.linalg.norm(g), 1e-300)
    history = [(0, u.copy(), f, float(np.linalg.norm(g)))]
    if log:
        log(history[-1])
    for it in range(1, iterations + 1):
        direction = -inverse_hessian @ g
        slope = float(g @ direction)
        if slope >= 0:  # not a descent direction: start again from the gradient
            inverse_hessian = np.eye(len(u)) * FIRST_STEP / max(np.linalg.norm(g), 1e-300)
            direction, slope = -inverse_hessian @ g, -float(g @ inverse_hessian @ g)
        step = 1.0
        while step > 1e-6:
            trial = value(u + step * direction)
            if trial <= f + ARMIJO * step * slope:
                break
            step *= 0.5
        else:
            break  # no step decreases f: at the precision of the run
        u_new = u + step * direction
        f_new, g_new = value_and_grad(u_new)
        s, y = u_new - u, g_new - g
        if s @ y > 1e-300:
            rho = 1.0 / (s @ y)
            eye = np.eye(len(u))
            inverse_hessian = (eye - rho * np.outer(s, y)) @ inverse_hessian @ (eye - rho * np.outer(y, s)) \
                + rho * np.outer(s, s)
        decrease = (f - f_new) / max(abs(f), 1e-300)
        u, f, g = u_new, f_new, g_new
        history.append((it, u.copy(), f, float(np.linalg.norm(g))))
        if log:
            log(history[-1])
        if decrease < tolerance or np.abs(s).max() < tolerance:
            break
    return u, history


def run_grid(seconds: float, bound: float, samples: int = 10) -> tuple:
    """(steps, dt, times): the fewest equal steps within 0.9 of the stability bound [s] that fill
    `seconds`, and `samples` times evenly over the run, each on the step grid."""
    steps = math.ceil(seconds / (0.9 * bound))
    dt = seconds / steps
    return steps, dt, np.round(seconds * np.arange(1, samples + 1) / samples / dt) * dt


def shaking_curl():
    """The demo's strand: a tight curl (4 mm radius, 1 cm pitch, 4 cm, 12 nodes)."""
    return Groom.curly(np.array([[0.0, 0.0, 0.0]]), np.array([[0.0, 0.6, -0.8]]), length=0.04, n_nodes=12,
                       curl_radius=0.004, curl_pitch=0.01)


def shake_keys(seconds: float, keys: int = 9, degrees: float = 10.0) -> np.ndarray:
    """Head poses [keys, 6]: a turn about the vertical back and forth by +-degrees."""
    t = np.linspace(0.0, seconds, keys)
    poses = np.zeros((keys, 6))
    poses[:, 2] = math.radians(degrees) * np.sin(2.0 * math.pi * t / seconds)
    return poses


def recover_material(*, seconds: float = 0.02, factor: float = 3.0, ellipticity: float = 2.0,
                     youngs_modulus: float = 3.0e9, drag: float = 3e-4, samples: int = 10,
                     iterations: int = 40, log=None) -> dict:
    """Recover Young's modulus [Pa] and air drag [N s/m^2] of a curl on a shaking head from its
    node positions at `samples` times, starting `factor` x off on both. Returns the iterations,
    the recovered values, their relative errors and the wall time."""
    groom = shaking_curl()
    start = {"youngs_modulus": youngs_modulus * factor, "drag": drag * factor}
    # a step stable for twice the stiffer of the truth and the start
    stiffest = 2.0 * max(youngs_modulus, start["youngs_modulus"])
    bound = stable_time_step(groom, [Material(youngs_modulus=stiffest, ellipticity=ellipticity)],
                             min(drag, start["drag"]))
    steps, dt, times = run_grid(seconds, bound, samples)
    clock = time.perf_counter()
    # one problem (its kernels compiled once): the reference motion first, then the fit from the start
    fit = Differentiable(groom, Material(youngs_modulus=youngs_modulus, ellipticity=ellipticity), dt=dt,
                         seconds=steps * dt, drag=drag, motion=shake_keys(seconds))
    loss = losses.positions(fit.positions(times), times)

    def values(u):
        return float(math.exp(u[0])), float(math.exp(u[1]))

    def value(u):
        e, nu = values(u)
        fit.update(youngs_modulus=e, drag=nu)
        try:
            return loss(fit.positions(times))[0]
        except SimulationDiverged:
            return math.inf

    def value_and_grad(u):
        e, nu = values(u)
        fit.update(youngs_modulus=e, drag=nu)
        f, grads = fit.value_and_grad(loss, wrt=["youngs_modulus", "drag"])
        return f, np.array([grads["youngs_modulus"] * e, grads["drag"] * nu])

    rows = []

    def record(entry):
        it, u, f, g = entry
        e, nu = values(u)
        rows.append({"iteration": it, "youngs_modulus": e, "drag": nu, "loss": f, "gradient": g,
                     "seconds": time.perf_counter() - clock})
        if log:
            log(rows[-1])

    u, _ = minimise(value_and_grad, value, np.log([start["youngs_modulus"], start["drag"]]),
                    iterations=iterations, log=record)
    e, nu = values(u)
    return {"truth": {"youngs_modulus": youngs_modulus, "drag": drag}, "start": start,
            "recovered": {"youngs_modulus": e, "drag": nu},
            "relative_error": {"youngs_modulus": abs(e / youngs_modulus - 1), "drag": abs(nu / drag - 1)},
            "iterations": rows, "wall_seconds": time.perf_counter() - clock, "steps": steps, "dt": dt}


def hang_as_drawn(*, seconds: float = 0.01, hold_seconds: float = 0.1, iterations: int = 60, log=None) -> dict:
    """Solve for the rest shape of a curl drawn sideways (so gravity bends it) such that it hangs
    as drawn: BFGS on the rest positions of its free nodes [mm from the drawn ones], the loss
    being the mean squared distance from the drawn shape at ten times over `seconds` of a run
    that starts at the drawn shape at rest. Then hold each answer for `hold_seconds` in the
    simulator (explicit, DER, quasistatic twist, its rest curvatures and twists from the answer)
    beside `th.sag_free`'s answer and the drawn shape taken as its own rest shape; returns each
    one's largest distance from the drawn shape [m]."""
    from ..hair.sagfree import sag_free
    from ..solver.simulator import Simulator
    drawn = Groom.curly(np.array([[0.0, 0.0, 0.0]]), np.array([[1.0, 0.0, -0.3]]), length=0.04, n_nodes=12,
                        curl_radius=0.004, curl_pitch=0.01)
    material = Material()
    drag = 3e-4
    steps, dt, times = run_grid(seconds, stable_time_step(drawn, [material], drag))
    problem = Differentiable(drawn, material, dt=dt, seconds=steps * dt, drag=drag,
                             initial_positions=drawn.positions)
    loss = losses.positions(np.repeat(drawn.positions[None], len(times), axis=0), times)
    unit = 1e-3  # the variables are millimetres

    def rest(u):
        positions = drawn.positions.copy()
        positions[:, 1:] += unit * u.reshape(positions[:, 1:].shape)
        return positions

    def value(u):
        problem.update(rest_positions=rest(u))
        try:
            return loss(problem.positions(times))[0]
        except SimulationDiverged:
            return math.inf

    def value_and_grad(u):
        problem.update(rest_positions=rest(u))
        f, grads = problem.value_and_grad(loss, wrt=["rest_positions"])
        return f, unit * grads["rest_positions"][:, 1:].ravel()

    clock = time.perf_counter()
    rows = []

    def record(entry):
        rows.append({"iteration": entry[0], "loss": entry[2], "gradient": entry[3],
                     "seconds": time.perf_counter() - clock})
        if log:
            log(rows[-1])

    u, _ = minimise(value_and_grad, value, np.zeros(drawn.positions[:, 1:].size), iterations=iterations,
                    log=record)
    solve_seconds = time.perf_counter() - clock
    value(u)  # the rest values of the answer
    ours = drawn.with_rest_curvature(problem.rest_kappa.to_numpy(), problem.rest_twist.to_numpy())
    theirs, _ = sag_free(drawn, material, twist="quasistatic")
    hold_steps = math.ceil(hold_seconds / dt)
    sag = {}
    for name, groom in (("drawn as rest shape", drawn), ("gradient solve", ours), ("sag_free", theirs)):
        sim = Simulator(groom, material, dt=dt, strain="der", drag=drag)
        sim.step(hold_steps)
        sag[name] = float(np.linalg.norm(sim.positions() - drawn.positions, axis=-1).max())
    return {"iterations": rows, "solve_seconds": solve_seconds, "sag_after_hold_m": sag,
            "hold_seconds": hold_steps * dt, "rest_shift_mm": float(np.abs(u).max())}


def gradient_cost(strands: int, seconds: float = 1.0) -> dict:
    """Wall time of a forward run and of a gradient (all eight inputs) for `strands` wavy
    strands (15 cm, 16 nodes) on a shaking head over `seconds`, at the explicit bound's step,
    and the process's peak resident memory [bytes] after both (measure one count per process)."""
    import resource
    roots = np.stack([np.arange(strands) % 40 * 0.005, np.arange(strands) // 40 * 0.005, np.zeros(strands)], axis=1)
    groom = Groom.wavy(roots, np.tile([[0.0, 0.0, -1.0]], (strands, 1)), length=0.15, n_nodes=16)
    material = Material()
    steps, dt, times = run_grid(seconds, stable_time_step(groom, [material] * strands, 3e-4))
    problem = Differentiable(groom, material, dt=dt, seconds=steps * dt, drag=3e-4, motion=shake_keys(seconds))
    clock = time.perf_counter()
    reference = problem.positions(times)  # compiles the forward kernels
    compile_forward = time.perf_counter() - clock
    loss = losses.positions(reference + 1e-3, times)
    clock = time.perf_counter()
    problem.value_and_grad(loss)  # compiles the gradient kernels
    first_gradient = time.perf_counter() - clock
    clock = time.perf_counter()
    problem.positions(times)
    forward = time.perf_counter() - clock
    clock = time.perf_counter()
    problem.value_and_grad(loss)
    gradient = time.perf_counter() - clock
    return {"strands": strands, "seconds": seconds, "steps": steps, "dt": dt, "segment_steps": problem.segment_steps,
            "forward_s": forward, "gradient_s": gradient, "ratio": gradient / forward,
            "first_forward_s": compile_forward, "first_gradient_s": first_gradient,
            "peak_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024}


def add_parser(sub):
    p = sub.add_parser("inverse", help="recover Young's modulus and drag of a curl from its motion by gradients")
    p.add_argument("--seconds", type=cli_real("--seconds", 0.0, 100.0, unit="s"), default=0.02,
                   help="length of the reference motion (with --cost: of each timed run) [s]")
    p.add_argument("--factor", type=cli_real("--factor", 0.0, 100.0), default=3.0,
                   help="how far off the start is (both values times this)")
    p.add_argument("--json", default=None, help="write the iterations and results to this JSON file "
                   "(default: none, the table only)")
    p.add_argument("--hang", action="store_true", help="instead: solve a sideways curl's rest shape so that it "
                   "hangs as drawn, and compare with th.sag_free")
    p.add_argument("--cost", type=cli_int_list("--cost", 1, 1_000_000), default=None, metavar="N,N,...",
                   help="instead: time a forward run and a gradient over --seconds for each strand count, each in "
                   "its own process for its peak memory (default: none, the material demo)")
    p.set_defaults(func=main)


def main(args) -> int:
    from ..runtime import init
    if args.cost:
        return cost_table(args.cost, args.seconds, args.json)
    init(precision="float64")
    if args.hang:
        return hang_table(args.json)
    print(f"{'it':>3} {'E [Pa]':>12} {'drag [N s/m^2]':>15} {'loss [m^2]':>12} {'wall [s]':>9}")
    result = recover_material(seconds=args.seconds, factor=args.factor, log=lambda r: print(
        f"{r['iteration']:3d} {r['youngs_modulus']:12.5e} {r['drag']:15.5e} {r['loss']:12.4e} {r['seconds']:9.1f}",
        flush=True))
    err = result["relative_error"]
    print(f"recovered E {result['recovered']['youngs_modulus']:.6g} Pa (error {err['youngs_modulus']:.2e}), "
          f"drag {result['recovered']['drag']:.6g} N s/m^2 (error {err['drag']:.2e}) in "
          f"{result['wall_seconds']:.1f} s ({result['steps']} steps of {result['dt']:.3g} s)")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=1, default=float)
    return 0


def cost_table(counts, seconds: float, json_path=None) -> int:
    """Print gradient_cost for each strand count, each measured in a child process."""
    import subprocess
    import sys
    rows = []
    print(f"{'strands':>7} {'steps':>6} {'forward [s]':>11} {'gradient [s]':>12} {'ratio':>6} {'peak [MiB]':>10}")
    for n in counts:
        code = ("import json, taichi_hair as th; th.init(precision='float64'); "
                "from taichi_hair.app.inverse import gradient_cost; "
                f"print(json.dumps(gradient_cost({int(n)}, {float(seconds)!r})))")
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
        if done.returncode != 0:
            lines = done.stderr.strip().splitlines() or ["(no message)"]
            raise RuntimeError(f"the cost run of {n} strands failed: {lines[-1]}")
        row = json.loads(done.stdout.strip().splitlines()[-1])
        rows.append(row)
        print(f"{n:7d} {row['steps']:6d} {row['forward_s']:11.2f} {row['gradient_s']:12.2f} {row['ratio']:6.2f} "
              f"{row['peak_bytes'] / 2**20:10.0f}", flush=True)
    if json_path:
        with open(json_path, "w") as f:
            json.dump(rows, f, indent=1)
    return 0


def hang_table(json_path=None) -> int:
    print(f"{'it':>3} {'loss [m^2]':>12} {'|gradient|':>11} {'wall [s]':>9}")
    result = hang_as_drawn(log=lambda r: print(f"{r['iteration']:3d} {r['loss']:12.4e} {r['gradient']:11.3e} "
                                               f"{r['seconds']:9.1f}", flush=True))
    print(f"rest shape solved in {result['solve_seconds']:.1f} s (rest nodes moved up to "
          f"{result['rest_shift_mm']:.3f} mm); "
          f"largest distance from the drawn shape after {result['hold_seconds']:.3f} s in the simulator:")
    for name, sag in result["sag_after_hold_m"].items():
        print(f"  {name:22s} {sag * 1e3:9.4f} mm")
    if json_path:
        with open(json_path, "w") as f:
            json.dump(result, f, indent=1, default=float)
    return 0
