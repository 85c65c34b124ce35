"""Rasterisation kernels: triangles into a depth buffer, hair segments into a k-buffer, and the
per-pixel compositing of both.

Depth keys. A fragment is the 64-bit key `float32 bits of depth << 32 | primitive id`; for
positive depths the integer order is the depth order, so `atomic_min` keeps the nearest
fragment and its primitive, race-free, on CPU and GPU alike. Colours are recomputed from the
primitive id when a pixel is resolved, so the buffers hold keys only.

Hair transparency. Each pixel keeps its K nearest hair fragments exactly (a k-buffer filled by
a chain of `atomic_min`: inserting swaps the key with each slot's larger value, so the slots
stay sorted and a key pushed out of the last slot is never among the K nearest). Fragments
pushed out are blended order-independently into a "tail" layer behind the K sorted ones:
opacity 1 - prod(1 - alpha) = 1 - exp(-sum tau), tau = -log(1 - alpha), and the tau-weighted
mean colour (4 atomic adds per fragment): the nearer strand always wins at a
crossing, and dense hair far behind still darkens and tints the pixel.

Anti-aliasing. A fibre of width w pixels covers a pixel by the overlap of the fibre's
cross-section [d - w/2, d + w/2] with the pixel's [-1/2, 1/2], d the distance from the pixel
centre to the centre line: box-filtered coverage, so a column sums to w for a horizontal fibre
of any width, sub-pixel fibres included. Along the fibre, each pixel centre belongs to the one
segment it projects into (t in [0, 1)), so joints of a straight polyline are not counted twice.
"""

import numpy as np
import taichi as ti

from .camera import f32, vec3f, vec4f
from .threads import spread_rows

vec2f = ti.types.vector(2, ti.f32)
vec3i = ti.types.vector(3, ti.i32)
u8 = ti.u8


@ti.func
def empty_key() -> ti.i64:
    """Key of an empty slot: depth +inf, beyond every fragment."""
    return ti.cast(0x7F800000, ti.i64) << 32


@ti.func
def pack(depth: f32, prim: ti.i32) -> ti.i64:
    return (ti.cast(ti.bit_cast(depth, ti.i32), ti.i64) << 32) | ti.cast(prim, ti.i64)


@ti.func
def key_prim(key: ti.i64) -> ti.i32:
    return ti.cast(key - ((key >> 32) << 32), ti.i32)


@ti.func
def key_depth(key: ti.i64) -> f32:
    return ti.bit_cast(ti.cast(key >> 32, ti.i32), f32)


@ti.kernel
def clear_frame(mesh_key: ti.types.ndarray(dtype=ti.i64, ndim=2),
                kbuf: ti.types.ndarray(dtype=ti.i64, ndim=3),
                tail: ti.types.ndarray(dtype=vec4f, ndim=2)):
    """Empty the depth buffer (H, W), k-buffer (H, W, K) and tail accumulator (H, W)."""
    for i, j in mesh_key:
        mesh_key[i, j] = empty_key()
        for k in range(kbuf.shape[2]):
            kbuf[i, j, k] = empty_key()
        tail[i, j] = vec4f(0.0, 0.0, 0.0, 0.0)


@ti.kernel
def clear_keys_2d(key: ti.types.ndarray(dtype=ti.i64, ndim=2)):
    spread_rows(key.shape[0], key.shape[1], clear_key, (key,))


@ti.func
def clear_key(key: ti.template(), i: ti.i32, j: ti.i32):
    key[i, j] = empty_key()


@ti.func
def pixel_centre(px: ti.i32, py: ti.i32) -> vec2f:
    return vec2f(ti.cast(px, f32) + f32(0.5), ti.cast(py, f32) + f32(0.5))


@ti.func
def sub_pixel_centre(px: ti.i32, py: ti.i32, j: ti.i32) -> vec2f:
    """The centre of sub-pixel j (row-major, EDGE_SAMPLES per side) of pixel (px, py): where
    `raster_edge_samples` takes the meshes' depths and `shading.shade_mesh` shades them."""
    side = f32(EDGE_SAMPLES * 1.0)
    return vec2f(ti.cast(px, f32) + (ti.cast(j % EDGE_SAMPLES, f32) + f32(0.5)) / side,
                 ti.cast(py, f32) + (ti.cast(j // EDGE_SAMPLES, f32) + f32(0.5)) / side)


@ti.func
def edge(a: vec2f, b: vec2f, p: vec2f) -> f32:
    """Twice the signed area of (a, b, p)."""
    return (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])


@ti.func
def barycentric(a: vec4f, b: vec4f, c: vec4f, p: vec2f) -> vec3f:
    """Screen-space barycentric weights of p in triangle (a, b, c); area must be non-zero."""
    a2, b2, c2 = vec2f(a[0], a[1]), vec2f(b[0], b[1]), vec2f(c[0], c[1])
    area = edge(a2, b2, c2)
    w0 = edge(b2, c2, p) / area
    w1 = edge(c2, a2, p) / area
    return vec3f(w0, w1, f32(1.0) - w0 - w1)


@ti.func
def perspective_weights(a: vec4f, b: vec4f, c: vec4f, w: vec3f) -> vec3f:
    """Screen barycentrics -> weights for interpolating world-space attributes."""
    q = vec3f(w[0] * a[3], w[1] * b[3], w[2] * c[3])
    return q / (q[0] + q[1] + q[2])


@ti.kernel
def raster_triangles(n: ti.i32, screen: ti.types.ndarray(dtype=vec4f, ndim=1),
                     faces: ti.types.ndarray(dtype=vec3i, ndim=1), near: f32,
                     key: ti.types.ndarray(dtype=ti.i64, ndim=2)):
    """Depth-test n triangles into key (H, W): nearest (depth, face) per pixel centre.
    screen (V,) from `camera.project_vertices`. One thread per triangle."""
    height, width = key.shape[0], key.shape[1]
    for f in range(n):
        a, b, c = screen[faces[f][0]], screen[faces[f][1]], screen[faces[f][2]]
        area = edge(vec2f(a[0], a[1]), vec2f(b[0], b[1]), vec2f(c[0], c[1]))
        if ti.min(a[2], b[2], c[2]) > near and ti.abs(area) > f32(1e-12):
            x0 = ti.max(ti.cast(ti.ceil(ti.min(a[0], b[0], c[0]) - f32(0.5)), ti.i32), 0)
            x1 = ti.min(ti.cast(ti.floor(ti.max(a[0], b[0], c[0]) - f32(0.5)), ti.i32), width - 1)
            y0 = ti.max(ti.cast(ti.ceil(ti.min(a[1], b[1], c[1]) - f32(0.5)), ti.i32), 0)
            y1 = ti.min(ti.cast(ti.floor(ti.max(a[1], b[1], c[1]) - f32(0.5)), ti.i32), height - 1)
            for py in range(y0, y1 + 1):
                for px in range(x0, x1 + 1):
                    p = pixel_centre(px, py)
                    w = barycentric(a, b, c, p)
                    if w[0] >= f32(0.0) and w[1] >= f32(0.0) and w[2] >= f32(0.0):
                        q = perspective_weights(a, b, c, w)
                        depth = q[0] * a[2] + q[1] * b[2] + q[2] * c[2]
                        ti.atomic_min(key[py, px], pack(depth, f))



# sub-pixels per side where mesh edges are anti-aliased (`mark_mesh_edges`, `shade_mesh`)
EDGE_SAMPLES = 3


@ti.kernel
def mark_mesh_edges(mesh_key: ti.types.ndarray(dtype=ti.i64, ndim=2), capacity: ti.i32,
                    count: ti.types.ndarray(dtype=ti.i32, ndim=1),
                    edge_index: ti.types.ndarray(dtype=ti.i32, ndim=2),
                    sub_key: ti.types.ndarray(dtype=ti.i64, ndim=2),
                    part: ti.types.ndarray(dtype=ti.i32, ndim=1)):
    """edge_index (H, W) = a slot (row of sub_key) for each pixel near a mesh edge: one of its
    8 neighbours differs in showing a mesh, in depth by over 2 %, or in which mesh it shows
    (part (F,): each face's mesh; where a neck meets a body, depth is continuous but the
    surfaces cross); -1 elsewhere (and past `capacity` slots). The slot's EDGE_SAMPLES^2 keys
    are cleared; count[0]: slots taken (start at 0). One thread per pixel (CPU: per row,
    `threads.spread_rows`)."""
    spread_rows(mesh_key.shape[0], mesh_key.shape[1], mark_mesh_edge,
                (mesh_key, capacity, count, edge_index, sub_key, part))


@ti.func
def mark_mesh_edge(mesh_key: ti.template(), capacity: ti.i32, count: ti.template(),
                   edge_index: ti.template(), sub_key: ti.template(), part: ti.template(),
                   py: ti.i32, px: ti.i32):
    """`mark_mesh_edges` for pixel (px, py)."""
    height, width = mesh_key.shape[0], mesh_key.shape[1]
    k = mesh_key[py, px]
    is_edge = 0
    for dy, dx in ti.static(ti.ndrange((-1, 2), (-1, 2))):
        k2 = mesh_key[ti.math.clamp(py + dy, 0, height - 1), ti.math.clamp(px + dx, 0, width - 1)]
        if (k == empty_key()) != (k2 == empty_key()):
            is_edge = 1
        elif k != empty_key():
            z1, z2 = key_depth(k), key_depth(k2)
            if ti.max(z1, z2) > ti.min(z1, z2) * f32(1.02):
                is_edge = 1
            elif part[key_prim(k)] != part[key_prim(k2)]:
                is_edge = 1
    slot = -1
    if is_edge:
        s = ti.atomic_add(count[0], 1)
        if s < capacity:
            slot = s
            for j in ti.static(range(EDGE_SAMPLES * EDGE_SAMPLES)):
                sub_key[s, j] = empty_key()
    edge_index[py, px] = slot


@ti.func
def sub_pixel_edge(pixels: ti.template(), slot: ti.i32):
    """(edge, n_mesh) of the pixel with edge slot `slot` (-1: none) in pixels (MeshPixelArgs):
    n_mesh of its EDGE_SAMPLES^2 sub-pixels hit a mesh, and they disagree (edge = 1): mesh and
    background, a depth step of over 2 % (a silhouette), or two meshes (where they cross)."""
    sub_key, part = ti.static(pixels.pixel_sub_key, pixels.pixel_part)
    n_mesh, z_lo, z_hi = 0, f32(3.0e38), f32(0.0)
    first_part, mixed = -1, 0
    full = EDGE_SAMPLES * EDGE_SAMPLES
    if slot >= 0:
        for j in ti.static(range(EDGE_SAMPLES * EDGE_SAMPLES)):
            k = sub_key[slot, j]
            if k != empty_key():
                n_mesh += 1
                z = key_depth(k)
                z_lo = ti.min(z_lo, z)
                z_hi = ti.max(z_hi, z)
                p = part[key_prim(k)]
                if first_part < 0:
                    first_part = p
                elif p != first_part:
                    mixed = 1
    edge = slot >= 0 and ((n_mesh > 0 and n_mesh < full)
                          or (n_mesh == full and (z_hi > z_lo * f32(1.02) or mixed == 1)))
    return ti.select(edge, 1, 0), n_mesh


@ti.kernel
def raster_edge_samples(n: ti.i32, screen: ti.types.ndarray(dtype=vec4f, ndim=1),
                        faces: ti.types.ndarray(dtype=vec3i, ndim=1), near: f32,
                        edge_index: ti.types.ndarray(dtype=ti.i32, ndim=2),
                        sub_key: ti.types.ndarray(dtype=ti.i64, ndim=2)):
    """Depth-test n triangles at the EDGE_SAMPLES x EDGE_SAMPLES sub-pixel centres of the
    pixels `mark_mesh_edges` gave a slot: sub_key[slot, dy * EDGE_SAMPLES + dx] = nearest
    (depth, face). One thread per triangle."""
    height, width = edge_index.shape[0], edge_index.shape[1]
    for f in range(n):
        a, b, c = screen[faces[f][0]], screen[faces[f][1]], screen[faces[f][2]]
        area = edge(vec2f(a[0], a[1]), vec2f(b[0], b[1]), vec2f(c[0], c[1]))
        if ti.min(a[2], b[2], c[2]) > near and ti.abs(area) > f32(1e-12):
            x0 = ti.max(ti.cast(ti.floor(ti.min(a[0], b[0], c[0])), ti.i32), 0)
            x1 = ti.min(ti.cast(ti.floor(ti.max(a[0], b[0], c[0])), ti.i32), width - 1)
            y0 = ti.max(ti.cast(ti.floor(ti.min(a[1], b[1], c[1])), ti.i32), 0)
            y1 = ti.min(ti.cast(ti.floor(ti.max(a[1], b[1], c[1])), ti.i32), height - 1)
            for py in range(y0, y1 + 1):
                for px in range(x0, x1 + 1):
                    slot = edge_index[py, px]
                    if slot >= 0:
                        for dy, dx in ti.static(ti.ndrange(EDGE_SAMPLES, EDGE_SAMPLES)):
                            p = sub_pixel_centre(px, py, dy * EDGE_SAMPLES + dx)
                            w = barycentric(a, b, c, p)
                            if w[0] >= f32(0.0) and w[1] >= f32(0.0) and w[2] >= f32(0.0):
                                q = perspective_weights(a, b, c, w)
                                depth = q[0] * a[2] + q[1] * b[2] + q[2] * c[2]
                                ti.atomic_min(sub_key[slot, dy * EDGE_SAMPLES + dx], pack(depth, f))

@ti.func
def coverage(p: vec2f, a: vec4f, b: vec4f, wa: f32, wb: f32) -> vec2f:
    """(coverage in [0, 1], t) of the pixel centred at p by the fibre from a to b with widths
    wa, wb [pixels]; t in [0, 1) is where p projects onto the segment (coverage 0 outside)."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    l2 = dx * dx + dy * dy
    cov, t = f32(0.0), f32(0.0)
    if l2 > f32(1e-12):
        t = ((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / l2
        if t >= f32(0.0) and t < f32(1.0):
            d = ti.sqrt((a[0] + t * dx - p[0]) ** 2 + (a[1] + t * dy - p[1]) ** 2)
            half = f32(0.5) * (wa + t * (wb - wa))
            cov = ti.math.clamp(ti.min(d + half, f32(0.5)) - ti.max(d - half, f32(-0.5)),
                                f32(0.0), f32(1.0))
    return vec2f(cov, t)


@ti.func
def fragment(e: ti.i32, px: ti.i32, py: ti.i32, seg: ti.template(), screen: ti.template(),
             width_px: ti.template(), rgba: ti.template()) -> vec4f:
    """(linear rgb, alpha) of hair segment e at pixel (px, py)."""
    i = seg[e]
    p = pixel_centre(px, py)
    cv = coverage(p, screen[i], screen[i + 1], width_px[i], width_px[i + 1])
    c = rgba[i] * (f32(1.0) - cv[1]) + rgba[i + 1] * cv[1]
    return vec4f(c[0], c[1], c[2], cv[0] * c[3])


@ti.func
def insert(kbuf: ti.template(), py: ti.i32, px: ti.i32, key: ti.i64) -> ti.i64:
    """Insert key into the pixel's sorted k-buffer; returns the key pushed out (or empty)."""
    v = key
    # slots only ever decrease, so a key behind the last slot now stays out of the K nearest
    if key > kbuf[py, px, kbuf.shape[2] - 1]:
        v = key
    else:
        k = 0
        while k < kbuf.shape[2] and v != empty_key():
            old = ti.atomic_min(kbuf[py, px, k], v)
            v = ti.max(old, v)
            k += 1
    return v


@ti.func
def blend_tail(f: vec4f, px: ti.i32, py: ti.i32, tail: ti.template()):
    """Add fragment f = (rgb, alpha) to the pixel's unordered tail: optical depth
    -log(1 - alpha) and the optical-depth-weighted colour, 4 atomic adds."""
    tau = -ti.log(f32(1.0) - ti.min(f[3], f32(0.999)))
    tail[py, px] += vec4f(f[0] * tau, f[1] * tau, f[2] * tau, tau)


@ti.func
def hair_pixel(e: ti.i32, px: ti.i32, py: ti.i32, a: vec4f, b: vec4f, seg: ti.template(),
               screen: ti.template(), width_px: ti.template(), rgba: ti.template(),
               mesh_key: ti.template(), kbuf: ti.template(), tail: ti.template()):
    """Fragment of segment e (screen endpoints a, b) at pixel (px, py): depth-test against the
    meshes, insert into the k-buffer, send whatever falls out to the tail."""
    i = seg[e]
    p = pixel_centre(px, py)
    cv = coverage(p, a, b, width_px[i], width_px[i + 1])
    if cv[0] > f32(0.0):
        t = cv[1]
        inv_w = a[3] + t * (b[3] - a[3])
        depth = (a[2] * a[3] + t * (b[2] * b[3] - a[2] * a[3])) / inv_w
        key = pack(depth, e)
        if (key >> 32) < (mesh_key[py, px] >> 32):
            out = insert(kbuf, py, px, key)
            if out == key:
                c = rgba[i] * (f32(1.0) - t) + rgba[i + 1] * t
                blend_tail(vec4f(c[0], c[1], c[2], cv[0] * c[3]), px, py, tail)
            elif out != empty_key():
                blend_tail(fragment(key_prim(out), px, py, seg, screen, width_px, rgba),
                           px, py, tail)


@ti.kernel
def raster_hair(n: ti.i32, seg: ti.types.ndarray(dtype=ti.i32, ndim=1),
                screen: ti.types.ndarray(dtype=vec4f, ndim=1),
                width_px: ti.types.ndarray(dtype=f32, ndim=1),
                rgba: ti.types.ndarray(dtype=vec4f, ndim=1), near: f32,
                mesh_key: ti.types.ndarray(dtype=ti.i64, ndim=2),
                kbuf: ti.types.ndarray(dtype=ti.i64, ndim=3),
                tail: ti.types.ndarray(dtype=vec4f, ndim=2)):
    """Insert the fragments of n hair segments (seg[e] -> seg[e] + 1) in front of the meshes
    into the k-buffer (H, W, K); fragments pushed out go to the tail (H, W). One thread per
    segment, walking the pixels near the segment column by column along its major axis."""
    height, width = mesh_key.shape[0], mesh_key.shape[1]
    for e in range(n):
        i = seg[e]
        a, b = screen[i], screen[i + 1]
        xmajor = ti.abs(b[0] - a[0]) >= ti.abs(b[1] - a[1])
        am, an = ti.select(xmajor, a[0], a[1]), ti.select(xmajor, a[1], a[0])
        bm, bn = ti.select(xmajor, b[0], b[1]), ti.select(xmajor, b[1], b[0])
        size_m, size_n = ti.select(xmajor, width, height), ti.select(xmajor, height, width)
        dm, dn = bm - am, bn - an
        length = ti.sqrt(dm * dm + dn * dn)
        if ti.min(a[2], b[2]) > near and length > f32(1e-6):
            # pixel centres with non-zero coverage lie within `reach` of the centre line
            reach = f32(0.5) * ti.max(width_px[i], width_px[i + 1]) + f32(0.5)
            ext_m = reach * ti.abs(dn) / length
            ext_n = reach * length / ti.abs(dm)
            m0 = ti.max(ti.cast(ti.ceil(ti.min(am, bm) - ext_m - f32(0.5)), ti.i32), 0)
            m1 = ti.min(ti.cast(ti.floor(ti.max(am, bm) + ext_m - f32(0.5)), ti.i32), size_m - 1)
            for m in range(m0, m1 + 1):
                centre = an + (ti.cast(m, f32) + f32(0.5) - am) * dn / dm
                n0 = ti.max(ti.cast(ti.ceil(centre - ext_n - f32(0.5)), ti.i32), 0)
                n1 = ti.min(ti.cast(ti.floor(centre + ext_n - f32(0.5)), ti.i32), size_n - 1)
                for q in range(n0, n1 + 1):
                    hair_pixel(e, ti.select(xmajor, m, q), ti.select(xmajor, q, m), a, b, seg,
                               screen, width_px, rgba, mesh_key, kbuf, tail)


@ti.kernel
def composite(seg: ti.types.ndarray(dtype=ti.i32, ndim=1),
              screen: ti.types.ndarray(dtype=vec4f, ndim=1),
              width_px: ti.types.ndarray(dtype=f32, ndim=1),
              rgba: ti.types.ndarray(dtype=vec4f, ndim=1),
              kbuf: ti.types.ndarray(dtype=ti.i64, ndim=3),
              tail: ti.types.ndarray(dtype=vec4f, ndim=2),
              base: ti.types.ndarray(dtype=vec3f, ndim=2),
              out_rgb: ti.types.ndarray(dtype=vec3f, ndim=2),
              out_alpha: ti.types.ndarray(dtype=f32, ndim=2)):
    """Per pixel: the K sorted hair fragments front to back, then the tail, over `base` (the
    shaded mesh or background). out_rgb linear radiance, out_alpha hair opacity, (H, W)."""
    for py, px in base:
        c = vec3f(0.0, 0.0, 0.0)
        trans = f32(1.0)
        k = 0
        # Taichi evaluates both sides of `and`: test the bound before reading the slot
        while k < kbuf.shape[2]:
            if kbuf[py, px, k] == empty_key():
                break
            f = fragment(key_prim(kbuf[py, px, k]), px, py, seg, screen, width_px, rgba)
            c += trans * f[3] * vec3f(f[0], f[1], f[2])
            trans *= f32(1.0) - f[3]
            k += 1
        tl = tail[py, px]
        if tl[3] > 0.0:
            a = f32(1.0) - ti.exp(-tl[3])
            c += trans * a * vec3f(tl[0], tl[1], tl[2]) / tl[3]
            trans *= f32(1.0) - a
        out_rgb[py, px] = c + trans * base[py, px]
        out_alpha[py, px] = f32(1.0) - trans


@ti.func
def encode_srgb(linear: f32) -> ti.u8:
    c = ti.math.clamp(linear, f32(0.0), f32(1.0))
    s = f32(12.92) * c
    if c > 0.0031308:
        s = f32(1.055) * ti.exp(f32(1.0 / 2.4) * ti.log(c)) - f32(0.055)
    return ti.cast(s * f32(255.0) + f32(0.5), ti.u8)


@ti.kernel
def srgb_thresholds(table: ti.types.ndarray(dtype=f32, ndim=1)):
    """table[k] = the least float32 c in [0, 1] that `encode_srgb` encodes as k or more, for
    k in 1..255 (table[0] = -inf): found by bisection on the bits of c (for c >= 0 their
    integer order is c's order). One thread per level."""
    for k in range(256):
        lo, hi = 0, 0x3F800000   # the bits of 0.0 and 1.0
        while lo < hi:
            mid = lo + (hi - lo) // 2
            if ti.cast(encode_srgb(ti.bit_cast(mid, f32)), ti.i32) >= k:
                hi = mid
            else:
                lo = mid + 1
        table[k] = ti.select(k == 0, f32(-3.0e38), ti.bit_cast(lo, f32))


@ti.func
def encode_srgb_table(linear: f32, table: ti.template()) -> ti.u32:
    """`encode_srgb` by binary search in its thresholds (`srgb_thresholds`): eight compares
    instead of libm's log and exp (calls); the same level for every input, as encode_srgb
    rises monotonically (a test checks both on millions of values)."""
    level = 0
    for b in ti.static(range(7, -1, -1)):
        if linear >= table[level + (1 << b)]:
            level += 1 << b
    return ti.cast(level, ti.u32)


_srgb_table: list = []


def srgb_table() -> ti.Ndarray:
    """The thresholds of `encode_srgb` (256,) float32 on the device, computed once."""
    if not _srgb_table:
        table = ti.ndarray(f32, (256,))
        srgb_thresholds(table)
        _srgb_table.append(table)
    return _srgb_table[0]


@ti.kernel
def finish(scale: ti.i32, rgb: ti.types.ndarray(dtype=vec3f, ndim=2),
           alpha: ti.types.ndarray(dtype=f32, ndim=2),
           out_rgb: ti.types.ndarray(dtype=vec3f, ndim=2),
           out_alpha: ti.types.ndarray(dtype=f32, ndim=2),
           image: ti.types.ndarray(dtype=ti.u32, ndim=1),
           table: ti.types.ndarray(dtype=f32, ndim=1)):
    """Box-filter scale x scale blocks of the supersampled rgb/alpha (H*s, W*s) down to
    (H, W), and encode the image (H W,), row-major, as 8-bit sRGB packed R | G << 8 | B << 16
    (a little-endian (H, W, 4) uint8 view: one 32-bit word per pixel reads back several times
    faster than three bytes, and a 1-D array faster than a 2-D one, `unpack_image`); table:
    `srgb_table()`. One thread per output
    pixel (CPU: per row, `threads.spread_rows`)."""
    spread_rows(out_alpha.shape[0], out_alpha.shape[1], finish_pixel,
                (scale, rgb, alpha, out_rgb, out_alpha, image, table))


@ti.func
def finish_pixel(scale: ti.i32, rgb: ti.template(), alpha: ti.template(), out_rgb: ti.template(),
                 out_alpha: ti.template(), image: ti.template(), table: ti.template(), py: ti.i32,
                 px: ti.i32):
    """`finish` for output pixel (px, py)."""
    c = vec3f(0.0, 0.0, 0.0)
    a = f32(0.0)
    for dy, dx in ti.ndrange(scale, scale):
        c += rgb[py * scale + dy, px * scale + dx]
        a += alpha[py * scale + dy, px * scale + dx]
    norm = f32(1.0) / ti.cast(scale * scale, f32)
    out_rgb[py, px] = c * norm
    out_alpha[py, px] = a * norm
    word = ti.u32(0)
    for ch in ti.static(range(3)):
        word |= encode_srgb_table(c[ch] * norm, table) << ti.u32(8 * ch)
    image[py * out_alpha.shape[1] + px] = word


def unpack_image(packed, height: int, width: int) -> np.ndarray:
    """(H, W, 3) uint8 sRGB from `finish`'s packed (H W,) image (a device ndarray)."""
    words = np.ascontiguousarray(packed.to_numpy(), dtype="<u4")
    return words.view(np.uint8).reshape(height, width, 4)[..., :3].copy()
