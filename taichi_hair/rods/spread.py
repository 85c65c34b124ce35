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
