"""Spreading a loop over strands across the CPU's threads.

Taichi's CPU backend (1.7) runs a kernel's top-level range-for in one contiguous block of
iterations per thread, each block at least CPU_BLOCK = 512 iterations long: a loop over 300
strands runs entirely on one thread, whatever the core count (measured on 2 cores: CPU time =
wall time). A kernel that loops over strands therefore loops over `count x spread_factor(count)`
iterations and lets every spread_factor-th one do strand `t // factor`: each thread's block then
holds about count / threads strands. On a GPU the factor is 1.

    factor = spread_factor(st.x.shape[0])
    for t in range(st.x.shape[0] * factor):
        if t % factor == 0:
            s = t // factor
            ...

Strands differ in work (those touching a collider take about twice the projection iterations of
the free ones, and a groom's strands touch in runs: its first half took 5-10 % more iterations
than its second on the main job), so the step's kernels take the strands in a mixed order
instead (`mixed_spread`, `mixed_strand`): strand (u x P) mod 2^k for u = t // factor, P the odd
number nearest 2^k / golden ratio, so each thread's block holds strands from the whole groom:

    span, factor = mixed_spread(st.x.shape[0])
    for t in range(span * factor):
        s = mixed_strand(t, span, factor, st.x.shape[0])
        if s >= 0:
            ...

Each strand's step reads and writes its own rows only, so the order changes no result.
"""

import taichi as ti

CPU_BLOCK = 512  # Taichi's least iterations per thread block on the CPU


def cpu_threads() -> int:
    """Threads a CPU kernel runs on (ti.init's cpu_max_num_threads), 0 on a GPU."""
    config = ti.lang.impl.current_cfg()
    return int(config.cpu_max_num_threads) if config.arch in (ti.x64, ti.arm64) else 0


@ti.func
def spread_factor(count):
    """Iterations per strand that give every CPU thread a block of about count / threads strands:
    ceil(CPU_BLOCK x threads / count), at least 1 (1 on a GPU). The same code for any thread
    count: a kernel compiled without it for one thread rounded differently (LLVM's choice),
    and results must not depend on the thread count."""
    return ti.max(1, (CPU_BLOCK * ti.static(cpu_threads()) + count - 1) // ti.max(count, 1))


@ti.func
def mixed_spread(count):
    """(span, factor) of a loop over count strands in a mixed order (`mixed_strand`): span the
    least power of two >= count, factor = spread_factor(span)."""
    span = 1
    while span < count:
        span *= 2
    return span, spread_factor(span)


@ti.func
def mixed_strand(t, span, factor, count):
    """The strand iteration t of a `mixed_spread` loop steps, or -1: (u x P) mod span for
    u = t // factor on every factor-th iteration, P odd (a permutation of [0, span)), where
    that is below count; on a GPU u itself (neighbouring threads, neighbouring strands)."""
    s = -1
    if t % factor == 0:
        u = t // factor
        if ti.static(cpu_threads() > 0):
            stride = ti.cast(ti.cast(span, ti.f32) * ti.f32(0.6180339887), ti.i64) | 1
            u = ti.cast((ti.cast(u, ti.i64) * stride) & ti.cast(span - 1, ti.i64), ti.i32)
        if u < count:
            s = u
    return s
