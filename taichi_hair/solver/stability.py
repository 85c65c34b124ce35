"""The explicit step's stability bound, and what to say when a run blows up anyway."""

import math
from dataclasses import dataclass

import numpy as np

DEFAULT_STABILITY_FACTOR = 0.5
# With strand contact the default factor leaves a margin: at 0.5 the step runs the stiffest
# bending mode at h omega = 1.97 (docs/model.md "Stability bound"), and contact pushes keep
# exciting that mode; cosseratbench's pile (a rope coiling onto itself) gained up to 0.33 of its
# energy in a frame after its clamp stopped at 0.5, and lost energy in every frame at 0.4
# (tests/test_cosseratbench.py).
CONTACT_STABILITY_FACTOR = 0.4


# A grab pulls every node within its radius toward one point and gathers the strands it holds
# into a ball (scenes/touch_comb.py: a 25 cm strand balled within 1.3 cm of the grab point,
# turning 60 to 100 degrees at every node, its nodes jittering at 2-3 m/s), which the fast
# projection fails to hold well inside the spring's own bound 2 c sqrt(m / k). Measured on
# touch_comb (c = 0.5, grab 0.01 N/m, its 1.71 ms spring bound), two grooms (equal edges, and
# equal arcs with edges up to 20 % short): diverged at 0.83, 0.89 and 1.19 ms, held 3 s at
# 0.60, 0.69, 0.76, 0.89 and 1.19 ms; a grab's bound is this fraction of the spring's (0.60 ms).
GRAB_GATHER_FACTOR = 0.35


def default_stability_factor(strand_contact: bool) -> float:
    """The explicit bound's factor a scene gets unless it names one: 0.5, or 0.4 with strand
    contact (`Simulator(strand_contact=...)`)."""
    return CONTACT_STABILITY_FACTOR if strand_contact else DEFAULT_STABILITY_FACTOR

# Kmoch's rule ties an elliptic strand's angles to its curvature binormals: the force of
# E(x, theta_kmoch(x)) is stiffer than bending alone, the more so the more elliptic the section.
# Measured on curled strands under gravity without drag (curl radius 3 mm to 1 cm): energy kept
# to 1e-8 J with no branch switches at 0.5 of the bending bound for ellipticity 1.3 and 1.5 (not
# at 0.59), 0.25 for 2.5 (not 0.5), 0.125 for 4 (not 0.25); the factor below has that margin.
def kmoch_bound_factor(ellipticity: float) -> float:
    """Extra factor on the bending bound of a curved elliptic strand under Kmoch's rule."""
    return min(0.5, 0.4 / (ellipticity - 1.0 / ellipticity))


class SimulationDiverged(RuntimeError):
    """A step produced non-finite or runaway values. The simulator's state was rolled back to
    the last healthy state before this was raised, so nothing returned or written is NaN."""

    def __init__(self, message, *, step, strand):
        super().__init__(message)
        self.step = step
        self.strand = strand


def rest_turns(points: np.ndarray) -> np.ndarray:
    """Turning angles [rad] at the interior nodes of one polyline [N, 3]."""
    e = np.diff(points, axis=0)
    lengths = np.linalg.norm(e, axis=1)
    cos_turn = np.clip(np.sum(e[1:] * e[:-1], axis=1) / (lengths[1:] * lengths[:-1]), -1.0, 1.0)
    return np.arccos(cos_turn)


def curvature_stiffening(turns: np.ndarray) -> float:
    """EI_eff / EI: how much stiffer than straight the stiffest bending mode of a strand with
    these interior turning angles [rad] may be, sec^4(phi_max / 2) (kb = 2 tan(phi / 2) outgrows
    phi). Checked against the measured stiffest mode of arcs, kinks, S-bends, random 3D shapes
    and curls (tests/test_stability_bound.py): it holds for both strain measures, for DER only up
    to 90 degree turns (docs/model.md "Stability bound")."""
    if len(turns) == 0:
        return 1.0
    return float(1.0 / np.cos(0.5 * np.max(turns)) ** 4)


# Under the rotation measure the rule overstates isolated sharp turns (a single 110 degree rest
# turn measures 0.97 of a straight chain against the rule's 9.2; tests/test_stability_bound.py):
# a strand whose rule exceeds MEASURE_ABOVE has its stiffest mode measured instead (Simulator).
MEASURE_ABOVE = 1.2


def stiffest_mode_ratio(points: np.ndarray, mass: np.ndarray, hessian: np.ndarray, ei_max: float,
                        linear_density: float) -> float:
    """omega_max^2 of one strand's bending (node 0 held) on its inextensible tangent space, over
    a straight chain's estimate (4 / ds^2)^2 EI_max / rho A with ds its shortest edge: the
    EI_eff / EI the bending bound needs for this shape. points [n, 3] m, mass [n] kg, hessian
    [3n, 3n] N/m of the elastic energy at these points (material angles held, which is stiffer
    than letting the twist relax)."""
    n = len(points)
    edges = np.diff(points, axis=0)
    jac = np.zeros((n - 1, 3 * n))
    for j, e in enumerate(edges):
        jac[j, 3 * j:3 * j + 3] = -e
        jac[j, 3 * j + 3:3 * j + 6] = e
    _, singular, vt = np.linalg.svd(jac[:, 3:])
    tangent = vt[int((singular > 1e-12 * singular.max()).sum()):].T
    k = 0.5 * (hessian + hessian.T)[3:, 3:]
    chol_inv = np.linalg.inv(np.linalg.cholesky(tangent.T @ np.diag(np.repeat(mass[1:], 3)) @ tangent))
    omega2 = float(np.linalg.eigvalsh(chol_inv @ (tangent.T @ k @ tangent) @ chol_inv.T).max())
    ds = float(np.linalg.norm(edges, axis=1).min())
    return omega2 / ((4.0 / ds**2) ** 2 * ei_max / linear_density)


def stable_time_step(groom, materials, drag: float, factor: float = DEFAULT_STABILITY_FACTOR,
                     kmoch: bool = False, measured: dict | None = None) -> float:
    """Largest explicit step h [s] the scene tolerates: the smallest of strand_time_steps."""
    return float(strand_time_steps(groom, materials, drag, factor, kmoch, measured).min())


def strand_time_steps(groom, materials, drag: float, factor: float = DEFAULT_STABILITY_FACTOR,
                      kmoch: bool = False, measured: dict | None = None) -> np.ndarray:
    """Largest explicit step h [s] each strand tolerates [S].

    Bending: the stiffest discrete bending mode of a strand has omega ~ 4 / ds^2 sqrt(EI / rho A)
    and symplectic Euler needs h omega < 2, so h < factor * ds^2 sqrt(rho A / EI_eff) with
    factor 0.5 and ds the shortest rest edge. EI_eff grows with the rest turning angle phi as
    EI / cos^4(phi/2), because kb = 2 tan(phi/2) stiffens under large curvature.
    Drag: alone, the explicit drag update needs h < 2 m / (drag l) = 2 rho A / drag. Together
    (x'' = -omega^2 x - gamma x', symplectic Euler) the step is stable iff h^2 omega^2 + 2 h gamma
    < 4, i.e. (h / h_bend)^2 + h / h_drag < 1: each bound alone is not enough when both are close
    (measured: a hair at 88 % of its bending bound with drag 5e-3 locks into a 2.4 m/s
    period-2 oscillation). factor applies to both bounds before they are combined.
    kmoch: the twist follows Kmoch's rule; curved elliptic strands get kmoch_bound_factor more.
    measured: {strand: EI_eff / EI} measured for this shape (stiffest_mode_ratio), taken in place
    of the rule for those strands (at least 1: a straight chain's margin).
    """
    bounds = np.empty(len(materials))
    for s, m in enumerate(materials):
        p = groom.strand(s)
        lengths = np.linalg.norm(np.diff(p, axis=0), axis=1)
        turns = rest_turns(p)
        stiffening = curvature_stiffening(turns)
        if measured and s in measured:
            stiffening = max(1.0, measured[s])
        ei_eff = max(m.bending_stiffness) * stiffening
        bend = factor * lengths.min() ** 2 * math.sqrt(m.linear_density / ei_eff)
        if kmoch and m.ellipticity > 1.0 and len(turns) and turns.max() > 0.0:
            bend *= kmoch_bound_factor(m.ellipticity)
        bounds[s] = bend if drag <= 0 else _damped_bound(bend, factor * 2.0 * m.linear_density / drag)
    return bounds


def _damped_bound(bend: float, damp: float) -> float:
    """The h > 0 with (h / bend)^2 + h / damp = 1 (written to stay accurate when damp >> bend)."""
    ratio = 2.0 * damp / bend
    return bend * ratio / (1.0 + math.sqrt(1.0 + ratio * ratio))


def wind_bounds(groom, max_air_speed: float, factor: float = DEFAULT_STABILITY_FACTOR) -> np.ndarray:
    """Largest step h [s] the wind allows each strand [S]: air moving at max_air_speed [m/s] drags
    nodes along at up to that speed, and the fast projection converges in a few iterations while
    a step moves a node at most about its shortest rest edge ds: h < 2 factor ds / max_air_speed,
    one edge per step at the default factor 0.5 (measured on the main job and the stability
    matrix's gales: docs/model.md "Stability bound"). math.inf without wind."""
    if max_air_speed <= 0:
        return np.full(groom.n_strands, math.inf)
    shortest = np.array([np.linalg.norm(np.diff(groom.strand(s), axis=0), axis=1).min()
                         for s in range(groom.n_strands)])
    return 2.0 * factor * shortest / max_air_speed


@dataclass(frozen=True)
class StabilityBound:
    """The explicit step's bound dt [s] and, in words naming the parameter, what sets it.
    reason: the words, or a function giving them (worded only when a refusal needs them)."""

    dt: float
    reason: object
    strands: np.ndarray | None = None  # [S] s: each strand's own bound (at most the scene's others)

    @property
    def cause(self) -> str:
        return self.reason() if callable(self.reason) else self.reason

    def tightened(self, strands: np.ndarray, cause: str) -> "StabilityBound":
        """This bound with each strand's bound at most `strands` [S] s; the cause is `cause`
        where the smallest of them is tighter than this bound."""
        tighter = strands if self.strands is None else np.minimum(self.strands, strands)
        if float(strands.min()) >= self.dt:
            return StabilityBound(self.dt, self.reason, tighter)
        return StabilityBound(float(strands.min()), cause, tighter)


def scene_bound(groom, materials, *, drag: float, air_speed: float, grabs=(), factor: float,
                kmoch: bool, measured: dict | None = None) -> StabilityBound:
    """The tightest of the scene's bounds: bending (with drag; tightened under Kmoch's rule),
    the wind (air_speed [m/s], the fastest air; each strand's over its own shortest edge), each
    grab spring (grabs: (name, stiffness [N/m], lightest free node's mass [kg]); GRAB_GATHER_FACTOR
    of the spring's own bound); its cause
    names the parameter that sets it. Drag is named when it at least halves the bending bound.
    Only the bound itself is computed here; the bending cause's comparison bounds (without drag,
    without Kmoch's factor) are computed when a refusal words it."""
    per_strand = strand_time_steps(groom, materials, drag, factor, kmoch=kmoch, measured=measured)
    with_drag = float(per_strand.min())

    def bending_cause() -> str:
        bend = stable_time_step(groom, materials, 0.0, factor, kmoch=kmoch, measured=measured)
        if with_drag < 0.5 * bend:
            return f"drag = {drag:g} N s/m per metre (the bending bound alone is {bend:.3g} s)"
        plain = stable_time_step(groom, materials, drag, factor) if kmoch else with_drag
        rule = (" (tightened for Kmoch's rule on elliptic curls: twist='quasistatic' has the plain "
                f"bending bound {plain:.3g} s)" if with_drag < plain else "")
        return ("the material's bending stiffness (youngs_modulus, radius) over the shortest "
                "segment and the sharpest rest turn of the groom" + rule)

    wind = wind_bounds(groom, air_speed, factor)
    candidates = [StabilityBound(with_drag, bending_cause),
                  StabilityBound(float(wind.min()),
                                 f"the wind (fastest air {air_speed:.3g} m/s must not move a node more "
                                 f"than a segment per step)")]
    # a grab spring k on the lightest free node m: h < 2 factor sqrt(m / k), and a fraction of
    # that for the ball it gathers the strands into
    candidates += [StabilityBound(GRAB_GATHER_FACTOR * 2.0 * factor * math.sqrt(mass / k),
                                  f"{name}.stiffness = {k:g} N/m (a grab gathers strands into a ball)")
                   for name, k, mass in grabs]
    tightest = min(candidates, key=lambda b: b.dt)
    shared = min([math.inf] + [b.dt for b in candidates[2:]])  # the bounds every strand shares
    return StabilityBound(tightest.dt, tightest.reason, np.minimum(np.minimum(per_strand, wind), shared))


def strand_substeps(dt: float, strands: np.ndarray, largest: int) -> tuple:
    """(M, m [S]): a step of dt [s] in M substeps, strand s taking m[s] of them at a time, so
    that it steps dt / m[s] within its own bound strands[s] [s]. m[s] divides M (the strands
    meet at every M-th of dt: head poses and the clock stay on one grid); among M from the
    largest strand's need up to twice that (at most `largest`), the one with the fewest strand
    steps, sum(m), and of those the smallest."""
    need = np.maximum(1, np.ceil(dt / strands - 1e-9)).astype(np.int64)
    top = int(need.max())
    best = None
    for total in range(top, max(top, min(2 * top, largest)) + 1):
        divisors = np.array([d for d in range(1, total + 1) if total % d == 0])
        m = divisors[np.searchsorted(divisors, need)]  # the smallest divisor covering each need
        if best is None or m.sum() < best[1].sum():
            best = (total, m)
    return best


def substeps_for(dt: float, bound: StabilityBound, strict: bool, max_substeps: int) -> int:
    """Substeps per step of dt [s] so that each is within the bound, or ValueError: past the
    bound with strict=True, or more than max_substeps."""
    if dt <= bound.dt:
        return 1
    if strict:
        raise ValueError(f"dt = {dt:.3g} s exceeds this scene's explicit stability bound "
                         f"{bound.dt:.3g} s (from the stiffest material, shortest segment, drag, "
                         f"grab springs and the starting shape); lower dt or pass strict=False to "
                         f"substep automatically")
    substeps = math.ceil(dt / bound.dt)
    if substeps > max_substeps:
        raise ValueError(f"dt = {dt:.3g} s would need {substeps} substeps of at most "
                         f"{bound.dt:.3g} s, more than max_substeps = {max_substeps}; the "
                         f"stability bound is set by {bound.cause}. Change that, lower dt, or "
                         f"raise max_substeps")
    return substeps


def likely_cause(dt_used: float, bound: float, cap_hits: int, max_speed: float,
                 residual: float = 0.0, implicit: bool = False) -> str:
    """A sentence naming the most likely reason a run diverged (implicit: the implicit step,
    which has no stability bound, ran)."""
    if residual > 1e-2:
        return (f"the inextensibility projection could not hold the edges (relative residual "
                f"{residual:.3g}): forces or motion too strong for a {dt_used:.3g} s step (gale wind, "
                f"violent head motion, large user force); lower dt")
    if implicit and not cap_hits:
        return (f"the implicit step's linearisation at dt = {dt_used:.3g} s (one solve per step) "
                f"left a node non-finite or faster than max_speed = {max_speed:g} m/s: an extreme "
                f"load or motion for this step; lower dt or add drag")
    if dt_used > bound and not implicit:
        return (f"the time step {dt_used:.3g} s exceeds the stability bound {bound:.3g} s "
                f"(strict=False substeps automatically; was the bound overridden?)")
    if cap_hits:
        return ("the inextensibility projection hit its iteration cap, so edges stretched; "
                "raise projection_iterations or lower dt")
    return (f"a node moved faster than max_speed = {max_speed:g} m/s: an extreme load (gale wind, "
            f"violent head motion, large user force) for this step; lower dt or add drag")
