"""Tiled front-to-back hair compositing (the default compositor).

The screen is cut into TILE x TILE pixel tiles. Each hair segment is binned into the tiles its
footprint touches and, within a tile, into one of N_BINS depth bins spanning the hair's depth
range (a counting sort: count, prefix sum, scatter; no atomics on pixels). Then one thread per
tile (tiles in a mixed order, `render.threads`, so the CPU's threads share the work) sorts
each bin's segments exactly by depth (Shell sort on 64-bit keys: depth bits and first vertex;
each bin just before the walk reaches it, so a tile that turns opaque leaves the
rest unsorted), walks them front to back (the segments' vertex data are cache misses: they
are requested 8 entries at a time ahead of the walk, `request_vertices`, and each segment's
ends read one iteration ahead) and blends each segment's fragments into the tile's pixels
front to back, with plain stores (the tile is its thread's alone; `+=` on an ndarray would
be an atomic add):

    C += T alpha c,   T *= 1 - alpha        (T: transmittance so far, 1 at the start)

skipping pixels already opaque (T < 1e-3) and stopping the tile once all of its pixels are.
Fragments are ordered by their segment's mid-depth, so ordering is exact between segments
and approximate only where two segments' depth ranges interleave within a pixel. Coverage is
the same box-filtered analytic coverage as the k-buffer compositor (`raster.coverage`).
The result per pixel: rgb = C + T * base (mesh or background), alpha = 1 - T.

Binning runs before shading: a tile whose every pixel shows a mesh nearer than a segment's
nearest point does not get it, and only the vertices of segments binned somewhere are shaded
(`render.frame`).
"""

import taichi as ti

from .bundles import HairArgs, TileBinArgs
from .camera import f32, vec3f, vec4f
from .threads import mixed, spread, spread_run

vec4i = ti.types.vector(4, ti.i32)

TILE = 16
N_BINS = 256
OPAQUE = 1e-3
# skip tiles where meshes hide a segment, and shade only vertices of binned segments; tests
# switch it off to check that this changes no pixel
CULL_HIDDEN = True
# entries per segment placed by the rank the counting pass kept (the rest through an atomic)
RANKED = 2
# segment-tile entries whose vertex data the compositor requests together (`request_vertices`)
PREFETCH = 8
_GAPS = (1750, 701, 301, 132, 57, 23, 10, 4, 1)


@ti.func
def segment_span(a: vec4f, b: vec4f, w: f32, width: ti.i32, height: ti.i32):
    """Pixel bounds (x0, x1, y0, y1) of the footprint of a segment from a to b with max width
    w [px]; x0 > x1 when it misses the image."""
    reach = f32(0.5) * w + f32(0.5)
    x0 = ti.max(ti.cast(ti.ceil(ti.min(a[0], b[0]) - reach - f32(0.5)), ti.i32), 0)
    x1 = ti.min(ti.cast(ti.floor(ti.max(a[0], b[0]) + reach - f32(0.5)), ti.i32), width - 1)
    y0 = ti.max(ti.cast(ti.ceil(ti.min(a[1], b[1]) - reach - f32(0.5)), ti.i32), 0)
    y1 = ti.min(ti.cast(ti.floor(ti.max(a[1], b[1]) + reach - f32(0.5)), ti.i32), height - 1)
    return x0, x1, y0, y1


@ti.func
def visible(a: vec4f, b: vec4f, near: f32) -> ti.i32:
    dx, dy = b[0] - a[0], b[1] - a[1]
    return ti.min(a[2], b[2]) > near and dx * dx + dy * dy > f32(1e-12)


@ti.func
def depth_bin(a: vec4f, b: vec4f, zrange: ti.types.vector(2, ti.f32)) -> ti.i32:
    z = f32(0.5) * (a[2] + b[2])
    return ti.math.clamp(ti.cast((z - zrange[0]) * zrange[1], ti.i32), 0, N_BINS - 1)


@ti.kernel
def depth_range(n: ti.i32, seg: ti.types.ndarray(dtype=ti.i32, ndim=1),
                screen: ti.types.ndarray(dtype=vec4f, ndim=1), near: f32, n_chunks: ti.i32,
                out: ti.types.ndarray(dtype=f32, ndim=1)):
    """out = (min, max) segment mid-depth [m] of the segments in front of `near`. Each of
    n_chunks threads reduces a contiguous run in registers, then one atomic pair per chunk."""
    out[0] = f32(3.0e38)
    out[1] = f32(-3.0e38)
    span, factor = spread(n_chunks)   # fewer chunks than 512 per CPU thread: spread them
    for step in range(span * factor):
        first, end = spread_run(step, span, factor, n, n_chunks)
        if first < end:
            lo, hi = f32(3.0e38), f32(-3.0e38)
            for e in range(first, end):
                a, b = screen[seg[e]], screen[seg[e] + 1]
                if ti.min(a[2], b[2]) > near:
                    z = f32(0.5) * (a[2] + b[2])
                    lo = ti.min(lo, z)
                    hi = ti.max(hi, z)
            ti.atomic_min(out[0], lo)
            ti.atomic_max(out[1], hi)


@ti.kernel
def tile_far_depth(mesh_key: ti.types.ndarray(dtype=ti.i64, ndim=2),
                   far: ti.types.ndarray(dtype=f32, ndim=1),
                   near: ti.types.ndarray(dtype=f32, ndim=1)):
    """far[tile] = the farthest mesh depth [m] over the tile's pixels (+inf where a pixel shows
    the background): hair wholly behind it in a tile has no fragment there; near[tile] = the
    nearest: hair wholly in front of it passes every pixel's depth test. One thread per
    tile."""
    height, width = mesh_key.shape[0], mesh_key.shape[1]
    tiles_x = (width + TILE - 1) // TILE
    tiles_y = (height + TILE - 1) // TILE
    for tile in range(tiles_x * tiles_y):
        tx0, ty0 = (tile % tiles_x) * TILE, (tile // tiles_x) * TILE
        d, dn = f32(0.0), f32(3.0e38)
        for py in range(ty0, ti.min(ty0 + TILE, height)):
            for px in range(tx0, ti.min(tx0 + TILE, width)):
                z = key_depth_of(mesh_key[py, px])
                d = ti.max(d, z)
                dn = ti.min(dn, z)
        far[tile] = d
        near[tile] = dn


@ti.kernel
def bin_segments(n: ti.i32, hair: HairArgs, near: f32, zrange: ti.types.vector(2, ti.f32),
                 width: ti.i32, height: ti.i32, far: ti.types.ndarray(dtype=f32, ndim=1),
                 scatter: ti.i32, bins: TileBinArgs):
    """Bin the hair's (HairArgs) segments into the tile grid's cells (TileBinArgs).
    Pass 1 (scatter = 0): count segments per (tile, depth bin) cell, and mark (= 1) the
    vertices of every segment binned somewhere (the only ones the frame shades). A segment's
    first RANKED entries are counted into `count`, keeping the count before it (its rank in
    the cell) in rank[e]; any further entries (long or wide segments) into `extra`. Pass 2
    (scatter = 1, after `exclusive_scan`): write each entry's sort key (`sort_key`) into
    items, at offsets[cell] + its rank (no atomic), further entries through the atomic
    cursor `extra`. A tile whose farthest mesh depth (`far`) lies in front of the segment's
    nearest point is skipped: every fragment there would fail the depth test. One thread per
    segment."""
    seg, screen, width_px, mark = ti.static(hair.hair_seg, hair.hair_screen, hair.hair_width_px,
                                            hair.hair_mark)
    count, extra, rank, offsets, items = ti.static(bins.bin_count, bins.bin_extra, bins.bin_rank,
                                                   bins.bin_offsets, bins.bin_items)
    tiles_x = (width + TILE - 1) // TILE
    for e in range(n):
        i = seg[e]
        a, b = screen[i], screen[i + 1]
        if visible(a, b, near):
            x0, x1, y0, y1 = segment_span(a, b, ti.max(width_px[i], width_px[i + 1]), width, height)
            if x0 <= x1 and y0 <= y1:
                bin_ = depth_bin(a, b, zrange)
                # fragment depths interpolate the ends' (float32 rounding: a relative margin)
                nearest = ti.min(a[2], b[2]) * f32(1.0 - 1e-5)
                entry = 0
                for ty in range(y0 // TILE, y1 // TILE + 1):
                    for tx in range(x0 // TILE, x1 // TILE + 1):
                        tile = ty * tiles_x + tx
                        if nearest < far[tile]:
                            cell = tile * N_BINS + bin_
                            if not scatter:
                                if entry < RANKED:
                                    rank[e, entry] = ti.atomic_add(count[cell], 1)
                                else:
                                    ti.atomic_add(extra[cell], 1)
                            else:
                                slot = 0
                                if entry < RANKED:
                                    slot = offsets[cell] + rank[e, entry]
                                else:
                                    slot = ti.atomic_add(extra[cell], 1)
                                items[slot] = sort_key(i, a, b)
                            entry += 1
                if entry > 0 and not scatter:
                    mark[i] = 1
                    mark[i + 1] = 1


@ti.kernel
def exclusive_scan(n: ti.i32, count: ti.types.ndarray(dtype=ti.i32, ndim=1),
                   extra: ti.types.ndarray(dtype=ti.i32, ndim=1),
                   offsets: ti.types.ndarray(dtype=ti.i32, ndim=1)) -> ti.i32:
    """offsets[k] = the cells before k's entries (count + extra), for k <= n; extra[k]
    becomes where cell k's further entries start (the scatter's cursor). Returns the total.
    Serial (n = tiles x bins, a few hundred thousand)."""
    total = 0
    ti.loop_config(serialize=True)
    for k in range(n):
        c, x = count[k], extra[k]
        offsets[k] = total
        extra[k] = total + c
        total += c + x
    offsets[n] = total
    return total


@ti.func
def vertex_of(key: ti.i64) -> ti.i32:
    """The first vertex of the segment of a `sort_key`."""
    return ti.cast(key & ti.i64(0x7FFFFFFF), ti.i32)


@ti.func
def sort_key(i: ti.i32, a: vec4f, b: vec4f) -> ti.i64:
    """float32 bits of the mid-depth of the segment from vertex i (a) to i + 1 (b) << 32 | i:
    for depths > 0 the integer order is (depth, index) order (segments are numbered in the
    order of their first vertex), so bins sort without looking the segments up, and the key
    holds the vertex compositing reads."""
    z = f32(0.5) * (a[2] + b[2])
    return (ti.cast(ti.bit_cast(z, ti.i32), ti.i64) << 32) | ti.cast(i, ti.i64)


@ti.func
def sort_bin(s0: ti.i32, s1: ti.i32, items: ti.template()):
    """Sort the keys items[s0:s1] in place: by segment mid-depth,
    ties by segment index (the scatter that filled the bin ran in any thread order: a total
    order makes the result, and so the frame, the same every time). Shell sort with Ciura's
    gaps."""
    for g in ti.static(_GAPS):
        if s1 - s0 > g:
            for k in range(s0 + g, s1):
                key = items[k]
                j = k
                # Taichi evaluates both sides of `and`: test the bound before reading items[j - g]
                while j - g >= s0:
                    prev = items[j - g]
                    if prev <= key:
                        break
                    items[j] = prev
                    j -= g
                items[j] = key


@ti.kernel
def composite_tiles(width: ti.i32, height: ti.i32, bins: TileBinArgs, hair: HairArgs,
                    mesh_key: ti.types.ndarray(dtype=ti.i64, ndim=2),
                    mesh_near: ti.types.ndarray(dtype=f32, ndim=1),
                    base: ti.types.ndarray(dtype=vec3f, ndim=2),
                    out_rgb: ti.types.ndarray(dtype=vec3f, ndim=2),
                    out_alpha: ti.types.ndarray(dtype=f32, ndim=2),
                    probes: ti.types.ndarray(dtype=ti.i32, ndim=1)):
    """Blend each tile's segments (bins: the scattered TileBinArgs; hair: the shaded
    HairArgs) front to back over `base`: out_rgb linear radiance, out_alpha hair opacity,
    (H, W). One thread per tile; out_alpha holds the transmittance while the tile is
    blended. probes[tile]: the sum of `request_vertices` (kept only so that its loads are not
    optimised away)."""
    offsets, items = ti.static(bins.bin_offsets, bins.bin_items)
    screen, width_px, rgba = ti.static(hair.hair_screen, hair.hair_width_px, hair.hair_rgba)
    tiles_x = (width + TILE - 1) // TILE
    tiles_y = (height + TILE - 1) // TILE
    n_tiles = tiles_x * tiles_y
    # tiles in a mixed order: the CPU's threads each take a contiguous run of the loop, and
    # in screen order one of them would get the middle of the picture, where the hair is
    span, factor = spread(n_tiles)
    ti.loop_config(block_dim=1)
    for step in range(span * factor):
        tile = mixed(step // factor, span)
        if step % factor != 0 or tile >= n_tiles:
            continue
        tx0, ty0 = (tile % tiles_x) * TILE, (tile // tiles_x) * TILE
        tx1, ty1 = ti.min(tx0 + TILE, width) - 1, ti.min(ty0 + TILE, height) - 1
        for py in range(ty0, ty1 + 1):
            for px in range(tx0, tx1 + 1):
                out_rgb[py, px] = vec3f(0.0, 0.0, 0.0)
                out_alpha[py, px] = f32(1.0)
        n_open = (tx1 - tx0 + 1) * (ty1 - ty0 + 1)
        near_tile = mesh_near[tile]
        # the tile's segments in depth order; each one's ends are read an iteration ahead:
        # the reads jump around the hair's arrays (cache misses) and overlap with blending
        # bins are sorted as the walk reaches them (one entry ahead), so a tile that turns
        # opaque leaves the bins behind unsorted
        k0, k1 = offsets[tile * N_BINS], offsets[(tile + 1) * N_BINS]
        next_bin, sorted_end = 0, k0
        while sorted_end <= ti.min(k0 + 1, k1 - 1) and next_bin < N_BINS:
            sorted_end = offsets[tile * N_BINS + next_bin + 1]
            sort_bin(offsets[tile * N_BINS + next_bin], sorted_end, items)
            next_bin += 1
        prefetched = request_vertices(k0, ti.min(k0 + PREFETCH, k1), items, screen, width_px, rgba)
        zero = vec4f(0.0, 0.0, 0.0, 0.0)
        a, b, wa, wb, ca, cb = zero, zero, f32(0.0), f32(0.0), zero, zero
        if k0 < k1:
            j = vertex_of(items[k0])
            a, b, wa, wb = screen[j], screen[j + 1], width_px[j], width_px[j + 1]
            ca, cb = rgba[j], rgba[j + 1]
        k = k0
        probe = 0
        while k < k1 and n_open > 0:
            if (k - k0) % PREFETCH == 0:
                probe += request_vertices(ti.min(k + PREFETCH, k1), ti.min(k + 2 * PREFETCH, k1),
                                          items, screen, width_px, rgba)
            kn = ti.min(k + 1, k1 - 1)
            while sorted_end <= kn and next_bin < N_BINS:
                sorted_end = offsets[tile * N_BINS + next_bin + 1]
                sort_bin(offsets[tile * N_BINS + next_bin], sorted_end, items)
                next_bin += 1
            j = vertex_of(items[kn])
            a_next, b_next = screen[j], screen[j + 1]
            wa_next, wb_next = width_px[j], width_px[j + 1]
            ca_next, cb_next = rgba[j], rgba[j + 1]
            # a segment wholly in front of the tile's nearest mesh passes every depth
            # test (fragment depths interpolate the ends': a relative margin for rounding)
            tested = ti.max(a[2], b[2]) * f32(1.0 + 1e-5) >= near_tile
            n_open -= blend_segment(a, b, wa, wb, ca, cb, vec4i(tx0, tx1, ty0, ty1), tested,
                                    mesh_key, out_rgb, out_alpha)
            a, b, wa, wb, ca, cb = a_next, b_next, wa_next, wb_next, ca_next, cb_next
            k += 1
        probes[tile] = prefetched + probe
        for py in range(ty0, ty1 + 1):
            for px in range(tx0, tx1 + 1):
                t = out_alpha[py, px]
                out_rgb[py, px] = out_rgb[py, px] + t * base[py, px]
                out_alpha[py, px] = f32(1.0) - t


@ti.func
def request_vertices(k0: ti.i32, k1: ti.i32, items: ti.template(), screen: ti.template(),
                     width_px: ti.template(), rgba: ti.template()) -> ti.i32:
    """Load the first vertex's screen position, width and colour of the entries items[k0:k1]
    (the second vertex shares their cache lines mostly) and return a sum of their bits: a
    software prefetch. The entries' vertices lie anywhere in the hair's arrays, so each read
    misses the caches; loaded one entry at a time the core waits out each miss in turn,
    requested together the misses overlap."""
    bits = 0
    for q in range(k0, k1):
        j = vertex_of(items[q])
        bits += (ti.bit_cast(screen[j][0], ti.i32) + ti.bit_cast(width_px[j], ti.i32)
                 + ti.bit_cast(rgba[j][0], ti.i32))
    return bits


@ti.func
def blend_segment(a: vec4f, b: vec4f, wa: f32, wb: f32, ca: vec4f, cb: vec4f, box: vec4i,
                  tested: ti.i32, mesh_key: ti.template(), out_rgb: ti.template(),
                  out_alpha: ti.template()) -> ti.i32:
    """Blend the fragments of a segment (screen ends a, b, widths wa, wb [px], shaded end
    colours ca, cb) inside the tile box = (tx0, tx1, ty0, ty1), [tx0, tx1] x [ty0, ty1] [px],
    behind what is there (depth-tested against the meshes only if `tested`); returns how
    many pixels became opaque. Walks the footprint column by column along the segment's major
    axis, as `raster.raster_hair` does. The coverage is `raster.coverage`'s with the
    segment's constants (1 / length^2, 1 / length) hoisted out of the pixel loop: a pixel
    costs no division or square root unless it is covered."""
    tx0, tx1, ty0, ty1 = box[0], box[1], box[2], box[3]
    closed = 0
    dx, dy = b[0] - a[0], b[1] - a[1]
    inv_l2 = f32(1.0) / (dx * dx + dy * dy)
    inv_len = ti.sqrt(inv_l2)
    dw = wb - wa
    za, dzw = a[2] * a[3], b[2] * b[3] - a[2] * a[3]
    dinv_w = b[3] - a[3]
    xmajor = ti.abs(dx) >= ti.abs(dy)
    am, an = ti.select(xmajor, a[0], a[1]), ti.select(xmajor, a[1], a[0])
    bm, bn = ti.select(xmajor, b[0], b[1]), ti.select(xmajor, b[1], b[0])
    lo_m, hi_m = ti.select(xmajor, tx0, ty0), ti.select(xmajor, tx1, ty1)
    lo_n, hi_n = ti.select(xmajor, ty0, tx0), ti.select(xmajor, ty1, tx1)
    dm, dn = bm - am, bn - an
    length = ti.sqrt(dm * dm + dn * dn)
    reach = f32(0.5) * ti.max(wa, wb) + f32(0.5)
    ext_m = reach * ti.abs(dn) / length
    ext_n = reach * length / ti.abs(dm)
    slope = dn / dm
    m0 = ti.max(ti.cast(ti.ceil(ti.min(am, bm) - ext_m - f32(0.5)), ti.i32), lo_m)
    m1 = ti.min(ti.cast(ti.floor(ti.max(am, bm) + ext_m - f32(0.5)), ti.i32), hi_m)
    for m in range(m0, m1 + 1):
        centre = an + (ti.cast(m, f32) + f32(0.5) - am) * slope
        n0 = ti.max(ti.cast(ti.ceil(centre - ext_n - f32(0.5)), ti.i32), lo_n)
        n1 = ti.min(ti.cast(ti.floor(centre + ext_n - f32(0.5)), ti.i32), hi_n)
        for q in range(n0, n1 + 1):
            px, py = ti.select(xmajor, m, q), ti.select(xmajor, q, m)
            t_old = out_alpha[py, px]
            if t_old > OPAQUE:
                ux = ti.cast(px, f32) + f32(0.5) - a[0]
                uy = ti.cast(py, f32) + f32(0.5) - a[1]
                s = (ux * dx + uy * dy) * inv_l2
                if s >= f32(0.0) and s < f32(1.0):
                    d = ti.abs(ux * dy - uy * dx) * inv_len
                    half = f32(0.5) * (wa + s * dw)
                    cov = ti.min(ti.min(d + half, f32(0.5)) - ti.max(d - half, f32(-0.5)),
                                 f32(1.0))
                    if cov > f32(0.0):
                        front = True
                        if tested:
                            depth = (za + s * dzw) / (a[3] + s * dinv_w)
                            front = depth < key_depth_of(mesh_key[py, px])
                        if front:
                            c = ca * (f32(1.0) - s) + cb * s
                            alpha = cov * c[3]
                            # a plain store: `+=` on an ndarray is an atomic add (a CAS loop
                            # per channel on the CPU), and only this tile's thread writes here
                            out_rgb[py, px] = (out_rgb[py, px]
                                               + t_old * alpha * vec3f(c[0], c[1], c[2]))
                            t_new = t_old * (f32(1.0) - alpha)
                            out_alpha[py, px] = t_new
                            if t_new <= OPAQUE:
                                closed += 1
    return closed


@ti.func
def key_depth_of(key: ti.i64) -> f32:
    return ti.bit_cast(ti.cast(key >> 32, ti.i32), f32)


def bin_hair(hd: dict, near, mesh_key) -> dict:
    """Bin uploaded, projected hair `hd` (see `render.frame`) into the screen tiles of
    mesh_key's (H, W) and depth bins, skipping tiles where the meshes hide it, and mark in
    hd["mark"] the vertices of the segments binned (the frame shades only those). Returns the
    bins for `composite_binned`: {"offsets", "items", "fragments": segment-tile entries,
    "tiles", "mesh_near", "args": the cells as a TileBinArgs}; hd["args"] is the hair's
    HairArgs."""
    from .runtime import buffer, chunks
    height, width = mesh_key.shape
    n_tiles = -(-width // TILE) * -(-height // TILE)
    zr = buffer("tile_zrange", f32, (2,))
    depth_range(hd["n_segments"], hd["seg"], hd["screen"], near,
                chunks(hd["n_segments"], 64, 1024), zr)
    lo, hi = (float(v) for v in zr.to_numpy())
    zrange = (lo, N_BINS / max(hi - lo, 1e-6)) if hi >= lo else (0.0, 1.0)
    far = buffer("tile_far", f32, (n_tiles,))
    mesh_near = buffer("tile_mesh_near", f32, (n_tiles,))
    if CULL_HIDDEN:
        tile_far_depth(mesh_key, far, mesh_near)
    else:
        far.fill(float("inf"))
        mesh_near.fill(0.0)
    count = buffer("tile_count", ti.i32, (n_tiles * N_BINS,))
    extra = buffer("tile_extra", ti.i32, (n_tiles * N_BINS,))
    offsets = buffer("tile_offsets", ti.i32, (n_tiles * N_BINS + 1,))
    rank = buffer("tile_rank", ti.i32, (max(hd["n_segments"], 1), RANKED))
    count.fill(0)
    extra.fill(0)
    hd["mark"].fill(0)
    args = (hd["n_segments"], hd["args"], near, zrange, width, height, far)
    bin_segments(*args, 0, TileBinArgs(bin_count=count, bin_extra=extra, bin_offsets=offsets,
                                       bin_rank=rank,
                                       bin_items=buffer("tile_items_dummy", ti.i64, (1,))))
    total = exclusive_scan(n_tiles * N_BINS, count, extra, offsets)
    capacity = 1 << max(int(total - 1).bit_length(), 10)   # powers of two: few reallocations
    items = buffer("tile_items", ti.i64, (capacity,))
    cells = TileBinArgs(bin_count=count, bin_extra=extra, bin_offsets=offsets, bin_rank=rank,
                        bin_items=items)
    bin_segments(*args, 1, cells)
    return {"offsets": offsets, "items": items, "fragments": int(total), "tiles": n_tiles,
            "mesh_near": mesh_near, "args": cells}


def composite_binned(bins: dict, hd: dict, mesh_key, base, out_rgb, out_alpha) -> None:
    """Blend the binned, shaded hair front to back per tile over `base` (H, W)."""
    from .runtime import buffer
    height, width = base.shape
    composite_tiles(width, height, bins["args"], hd["args"], mesh_key, bins["mesh_near"], base,
                    out_rgb, out_alpha, buffer("tile_probes", ti.i32, (bins["tiles"],)))

