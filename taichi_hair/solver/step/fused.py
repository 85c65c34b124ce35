"""The fused and staged launches: many steps per launch, or the stages in launches of their own."""

from dataclasses import asdict

import taichi as ti

from ...rods.arrays import Ints2, Vec3s1, Vec3s2
from ...rods.spread import mixed_spread, mixed_strand
from .bundles import ContactArgs, DriveArgs, gather_scalars, ModelArgs, ScalarArgs, StateArgs
from .plan import BAD, STRIDE, StageFlags
from .stages import STAGE_FUNCS, strand_place_root


@ti.kernel
def advance_strands(n_steps: int, fl: ti.template(), sa: ScalarArgs, md: ModelArgs, st: StateArgs, dr: DriveArgs,
                    co: ContactArgs):
    """n_steps steps of sa.h [s] from step index sa.k0 (time k0 h) for every strand (head poses
    as in the module doc; tool_points[k] are the tools at the start of step k). With fl.strides
    strand s steps c = counters[s, STRIDE] of them at a time (c h [s] from every c-th step; c
    divides n_steps). counters[s, BAD] = the first step where strand s failed (that strand stops
    there), -1 if none. One thread per strand, the strands in a mixed order (rods.spread)."""
    sc = gather_scalars(sa)
    span, factor = mixed_spread(st.x.shape[0])
    for t in range(span * factor):
        s = mixed_strand(t, span, factor, st.x.shape[0])
        if s >= 0:
            st.counters[s, BAD] = -1
            own = sc
            if ti.static(fl.strides):
                own.stride = ti.max(1, st.counters[s, STRIDE])
                own.h = sc.h * own.stride
            for k in range(n_steps):
                if k % own.stride == 0:
                    bad = 0
                    for stage in ti.static(STAGE_FUNCS):
                        bad += stage(s, k, fl, own, md, st, dr, co)
                    if bad:
                        st.counters[s, BAD] = k
                        break


def compiled_variants() -> list[dict]:
    """The stage flags of every compiled instance of the fused kernel in this process: a stage
    whose flag is False in every instance was never compiled (nor run). Reads Taichi's
    template-instance table."""
    keys = advance_strands._primal.mapper.mapping
    return [asdict(next(part for part in key if isinstance(part, StageFlags))) for key in keys]




@ti.kernel
def run_stages(first: ti.template(), last: ti.template(), fl: ti.template(), sa: ScalarArgs, md: ModelArgs,
               st: StateArgs, dr: DriveArgs, co: ContactArgs):
    """Stages first..last-1 of STAGES for one step of every strand; counters[s, BAD] is reset
    by the launch that runs the first stage and set to 0 where a stage failed. One thread per
    strand, the strands in a mixed order (rods.spread)."""
    sc = gather_scalars(sa)
    span, factor = mixed_spread(st.x.shape[0])
    for t in range(span * factor):
        s = mixed_strand(t, span, factor, st.x.shape[0])
        if s >= 0:
            if ti.static(first == 0):
                st.counters[s, BAD] = -1
            for stage in ti.static(STAGE_FUNCS[first:last]):
                if stage(s, 0, fl, sc, md, st, dr, co):
                    st.counters[s, BAD] = 0


@ti.kernel
def place_roots(head: Vec3s2, root_frame: Vec3s2, x: ti.types.ndarray(ndim=2), root_t: Vec3s1, root_u: Vec3s1):
    """Root nodes and root reference frames at head pose 1. One thread per strand."""
    for s in range(x.shape[0]):
        strand_place_root(s, head, 1, root_frame, x, root_t, root_u, 0)




@ti.kernel
def clear_bad(counters: Ints2):
    for s in range(counters.shape[0]):
        counters[s, BAD] = -1


