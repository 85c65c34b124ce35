"""Loop orders that give every CPU thread an even share of uneven work.

Taichi's CPU back end (1.7) splits a kernel's top-level range-for into one contiguous block of
iterations per thread, each at least 512 long, and `ti.loop_config(block_dim=...)` does not
change that (measured on 2 cores: a loop of 32,768 iterations whose first half held all the
work took as long as one whose every iteration did, its CPU time equal to its wall time; 600
even iterations ran on one thread, 1,200 on two). Screen tiles differ in work by orders of magnitude (the hair
fills the middle of the picture), so a loop over them in screen order leaves one thread with
most of it.

The same holds for any loop of fewer than 512 iterations per thread (the rows of an image or
a shadow map: 480 rows ran on one thread), and for pixels or vertices whose work is uneven
(the mesh fills the bottom of the picture, the shaded hair vertices lie in runs).

`mixed(u, span)` visits the items of a loop in a well-mixed order: item (u x P) mod span for
span a power of two and P the odd number nearest span / golden ratio, so any contiguous run of
iterations touches items spread evenly over the whole range (and so over the screen). The loop
runs over span x factor iterations, every factor-th one doing an item, so that each thread's
block has its share even when the items are fewer than 512 per thread (`spread_item`):

    span, factor = spread(n)
    for t in range(span * factor):
        item = spread_item(t, span, factor, n)
        if item >= 0:
            ...

Items are rows (`spread_rows`, for the kernels over an image or a shadow map) or runs of
consecutive vertices or segments (`spread_run`), each walked in order by one thread, so memory
is still read in order within an item.

On a GPU the factor is 1 and `spread_item` keeps the items in order (`mixed` alone changes nothing
but which thread does what).
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


@ti.func
def spread_item(t, span, factor, n):
    """The item that iteration t of a loop over span x factor iterations (`spread(n)`) does:
    mixed(t // factor, span) on every factor-th iteration where that is below n, else -1. On a
    GPU the factor is 1 and items keep their order (t itself): neighbouring threads then read
    neighbouring items, as the GPU's memory wants."""
    item = -1
    if t % factor == 0:
        u = t // factor
        if ti.static(cpu_threads() > 0):
            u = mixed(u, span)
        if u < n:
            item = u
    return item


@ti.func
def spread_run(t, span, factor, n, n_runs):
    """Bounds [lo, hi) of the run of items that iteration t of a spread loop over n_runs runs
    (`spread(n_runs)`) does: n items cut into n_runs consecutive runs, walked in order within
    a run; (0, 0) for iterations that do none."""
    lo, hi = 0, 0
    r = spread_item(t, span, factor, n_runs)
    if r >= 0:
        size = (n + n_runs - 1) // n_runs
        lo, hi = r * size, ti.min(n, (r + 1) * size)
    return lo, hi


@ti.func
def spread_rows(height, width, pixel: ti.template(), args: ti.template()):
    """pixel(*args, py, px) for every pixel of a (height, width) image or map: on the CPU each
    row walked in order by one thread, the rows in the mixed order over the threads (a loop
    over rows in screen order ran on one thread below 1,024 rows, and leaves uneven rows to
    one thread); on a GPU one thread per pixel. Call it at a kernel's top level: its loop is
    the kernel's parallel loop."""
    if ti.static(cpu_threads() > 0):
        span, factor = spread(height)
        for t in range(span * factor):
            py = spread_item(t, span, factor, height)
            if py >= 0:
                for px in range(width):
                    pixel(*args, py, px)
    else:
        for py, px in ti.ndrange(height, width):
            pixel(*args, py, px)
