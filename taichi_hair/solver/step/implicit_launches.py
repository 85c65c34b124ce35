"""The implicit step's launches: its integration (predictor and length corrections) in kernels of
its own, the other stages around it."""

import taichi as ti

from ...rods.arrays import BlockMats3, BlockVecs2, Ints1, Ints2, Points2, Scalars2, vec3, Vec3s2, Vec3s3
from ...rods.linalg import block_pentadiagonal_solve
from ...rods.state import HIST_DX, HIST_ELASTIC, HIST_V
from ..collisions import head_poses
from ..implicit import (CORRECTION_TOL, length_residual, MAX_CORRECTIONS, strand_implicit_assemble,
                        strand_implicit_finish)
from .bundles import ContactArgs, DriveArgs, gather_scalars, ModelArgs, ScalarArgs, StateArgs, StepBundles
from .fused import run_stages
from .plan import BAD, TWIST_NONE
from ...rods.spread import spread_factor
from .stages import INTEGRATION, place_root_and_pins, stage_forces, STAGE_FUNCS, STAGES


# ---- the implicit step's driver: its integration in launches of its own -------------------------
# A kernel's compile time grows faster than its size, and the implicit step's predictor and each
# of its length corrections hold a block assembly and a solve: one kernel holding them (and the
# other stages) compiled for minutes (docs/architecture.md, "Compile time"). So each round of
# the integration (the predictor, then up to MAX_CORRECTIONS corrections) is three launches:
# assemble, solve (implicit_solve: one kernel for every round, taking only the arrays it reads,
# since a launch costs ~15 us per array) and take the solution; a correction round runs only
# while some strand needs it.
ASSEMBLE, FINISH = range(2)
ROUNDS = MAX_CORRECTIONS + 1  # a step's rounds: the predictor and its corrections


@ti.func
def implicit_round(s, k, j, node_count: ti.template(), inv_mass: ti.template(), rest_length: ti.template(),
                   x: ti.template(), counters: ti.template()):
    """1 if strand s takes round j of step k's implicit solves, else 0: it has not failed in an
    earlier step of the launch group, and round j is the predictor (0), the first correction (1)
    or a later one while an edge is off by more than CORRECTION_TOL (x is the same in a round's
    three launches: only the last moves it)."""
    bad = counters[s, BAD]
    take = 0
    if bad < 0 or bad == k:
        take = 1
        if j >= 2:
            if length_residual(s, node_count, inv_mass, rest_length, x) <= CORRECTION_TOL:
                take = 0
    return take


@ti.kernel
def implicit_part(part: ti.template(), correction: ti.template(), forces: ti.template(), step_round: ti.i32,
                  fl: ti.template(), sa: ScalarArgs, md: ModelArgs, st: StateArgs, dr: DriveArgs, co: ContactArgs,
                  more: ti.template()):
    """The assembly (ASSEMBLE) or the solution's update (FINISH) of round j of step k's implicit
    integration (k as advance_strands' k) for every strand that takes it (implicit_round);
    step_round = k ROUNDS + j, one argument: the kernel's arguments are at Taichi's cap of 64
    numbers and arrays (the bundles' members count one each). correction: 0 the predictor
    (round 0), 1 a length correction (implicit.py); forces: the forces stage first (the
    predictor's ASSEMBLE of a fused step, where it also resets counters[s, BAD] at k = 0). The
    predictor's FINISH places the root and the pins; a correction's sets more[None] = 1 (a 0-d
    int field, for the same cap) where an edge is still off by more than CORRECTION_TOL.
    One thread per strand."""
    sc = gather_scalars(sa)
    k = step_round // ROUNDS
    j = step_round % ROUNDS
    factor = spread_factor(st.x.shape[0])
    for t in range(st.x.shape[0] * factor):
        if t % factor == 0:
            s = t // factor
            if ti.static(forces):
                if k == 0:
                    st.counters[s, BAD] = -1
            if implicit_round(s, k, j, md.node_count, md.inv_mass, md.rest_length, st.x, st.counters):
                if ti.static(part == ASSEMBLE):
                    bad = 0
                    if ti.static(forces):
                        bad += stage_forces(s, k, fl, sc, md, st, dr, co)
                    strand_implicit_assemble(s, k, correction, sc.h, sc.drag,
                                             ti.static(fl.twist_mode != TWIST_NONE), fl, sc, md, st, dr, co)
                    if bad:
                        st.counters[s, BAD] = k
                if ti.static(part == FINISH):
                    strand_implicit_finish(s, correction, sc.h, md, st)
                    if ti.static(correction == 0):
                        now, _ = head_poses(k, fl)
                        place_root_and_pins(s, k, now, fl, sc, md, st, dr)
                    else:
                        if length_residual(s, md.node_count, md.inv_mass, md.rest_length, st.x) > CORRECTION_TOL:
                            more[None] = 1


@ti.kernel
def implicit_solve(k: ti.i32, j: ti.i32, node_count: Ints1, inv_mass: Scalars2, rest_length: Scalars2, x: Points2,
                   counters: Ints2, blocks: BlockMats3, block_rhs: BlockVecs2):
    """Solve the systems of round j of step k (implicit_part's ASSEMBLE) in place
    (linalg.block_pentadiagonal_solve); counters[s, BAD] = k where a factorisation failed (a
    non-finite state). One thread per strand."""
    factor = spread_factor(x.shape[0])
    for t in range(x.shape[0] * factor):
        if t % factor == 0:
            s = t // factor
            if implicit_round(s, k, j, node_count, inv_mass, rest_length, x, counters):
                if block_pentadiagonal_solve(s, node_count[s], blocks, block_rhs):
                    counters[s, BAD] = k


@ti.kernel
def implicit_stages(first: ti.template(), last: ti.template(), k: ti.i32, fl: ti.template(), sa: ScalarArgs,
                    md: ModelArgs, st: StateArgs, dr: DriveArgs, co: ContactArgs):
    """STAGES first..last-1 of step k (after the implicit integration) for every strand that has
    not failed in an earlier step; counters[s, BAD] = k where one fails. One thread per strand."""
    sc = gather_scalars(sa)
    factor = spread_factor(st.x.shape[0])
    for t in range(st.x.shape[0] * factor):
        if t % factor == 0:
            s = t // factor
            if st.counters[s, BAD] < 0 or st.counters[s, BAD] == k:
                bad = 0
                for stage in ti.static(STAGE_FUNCS[first:last]):
                    bad += stage(s, k, fl, sc, md, st, dr, co)
                if bad:
                    st.counters[s, BAD] = k


_CORRECTION_FLAG = []


def correction_flag():
    """The 0-d int field implicit_part's FINISH raises when a strand needs another correction
    (made on first use: a field needs Taichi initialised)."""
    if not _CORRECTION_FLAG:
        _CORRECTION_FLAG.append(ti.field(ti.i32, shape=()))
    return _CORRECTION_FLAG[0]


def implicit_integrate(bundles: StepBundles, args: tuple, k: int, forces: bool) -> None:
    """Step k's implicit integration (with `forces`, the forces stage first): the predictor,
    then rounds of length corrections while a strand needs one (implicit_round), at most
    MAX_CORRECTIONS; args: implicit_part's from fl on (flags and the bundles)."""
    model, state = bundles.rods
    arrays_ = (model.node_count, model.inv_mass, model.rest_length, state.x, state.counters, state.blocks,
               state.block_rhs)
    more = correction_flag()
    for j in range(ROUNDS):
        if j >= 2 and not more[None]:
            break
        more[None] = 0
        correction = min(j, 1)
        implicit_part(ASSEMBLE, correction, forces and j == 0, k * ROUNDS + j, *args, more)
        implicit_solve(k, j, *arrays_)
        implicit_part(FINISH, correction, False, k * ROUNDS + j, *args, more)


def advance_implicit(bundles: StepBundles, args: tuple, n_steps: int) -> None:
    """n_steps implicit steps in launches (as advance_strands' steps); args: implicit_part's
    from fl on."""
    for k in range(n_steps):
        implicit_integrate(bundles, args, k, True)
        implicit_stages(INTEGRATION + 1, len(STAGES), k, *args)


def run_stage_range(bundles: StepBundles, first: int, last: int, args: tuple) -> None:
    """run_stages(first, last, *args), with the implicit step's integration (args[0].implicit)
    in launches of its own (implicit_integrate)."""
    if not (args[0].implicit and first <= INTEGRATION < last):
        run_stages(first, last, *args)
        return
    if first < INTEGRATION:
        run_stages(first, INTEGRATION, *args)
    implicit_integrate(bundles, args, 0, False)
    if INTEGRATION + 1 < last:
        run_stages(INTEGRATION + 1, last, *args)


@ti.kernel
def seed_history(h: float, node_count: Ints1, v: Vec3s2, history: Vec3s3, tension: Scalars2):
    """Start the implicit step's history as if each node had moved at its present velocity for
    one step of h [s]: v_prev = v, dx_prev = h v (BDF2's first step is then second order); no
    tension or earlier elastic force known yet (NaN)."""
    for s, i in ti.ndrange(v.shape[0], v.shape[1]):
        if i < node_count[s]:
            history[s, i, HIST_V] = v[s, i]
            history[s, i, HIST_DX] = h * v[s, i]
            history[s, i, HIST_ELASTIC] = vec3(ti.math.nan)
            if i < tension.shape[1]:
                tension[s, i] = 0.0
