"""Loop orders that give every CPU thread an even share of uneven work.

Taichi's CPU back end (1.7) splits a kernel's top-level range-for into one contiguous block of
iterations per thread, each at least 512 long, and `ti.loop_config(block_dim=...)` does not
change that (measured on 2 cores: a loop of 32,768 iterations whose first half held all the
work took as long as one whose every iteration did, its CPU time equal to its wall time; 600
even iterations ran on one thread, 1,200 on two). Screen tiles differ in work by orders of magnitude (the hair
fills the middle of the picture), so a loop over them in screen order leaves one thread with
most of it.

`mixed(u, span)` visits the items of a loop in a well-mixed order: item (u x P) mod span for
span a power of two and P the odd number nearest span / golden ratio, so any contiguous run of
iterations touches items spread evenly over the whole range (and so over the screen). The loop
runs over span x factor iterations, every factor-th one doing an item, so that each thread's
block has its share even when the items are fewer than 512 per thread:

    span, factor = spread(n)
    for t in range(span * factor):
        if t % factor == 0:
            item = mixed(t // factor, span)
            if item < n:
                ...

On a GPU the factor is 1 and the order changes nothing but which thread does what.
"""

import taichi as ti

CPU_BLOCK = 512  # Taichi's least iterations per thread block on the CPU


def cpu_threads() -> int:
    """Threads a CPU kernel runs on (ti.init's cpu_max_num_threads), 0 on a GPU."""
    config = ti.lang.impl.current_cfg()
    return int(config.cpu_max_num_threads) if config.arch in (ti.x64, ti.arm64) else 0


@ti.func
def spread(n):
    """(span, factor) for a loop over n items: span the least power of two >= n, factor the
    iterations per item that give every CPU thread a block of about span / threads items
    (at least 1; 1 on a GPU). The same code for any thread count."""
    span = 1
    while span < n:
        span *= 2
    factor = ti.max(1, (CPU_BLOCK * ti.static(cpu_threads()) + span - 1) // span)
    return span, factor


@ti.func
def mixed(u, span):
    """Item of iteration u (0 <= u < span, span a power of two) in the golden-ratio order:
    (u x P) mod span with P odd, a permutation of [0, span)."""
    stride = ti.cast(ti.cast(span, ti.f32) * ti.f32(0.6180339887), ti.i64) | 1
    return ti.cast((ti.cast(u, ti.i64) * stride) & ti.cast(span - 1, ti.i64), ti.i32)
