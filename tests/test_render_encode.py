"""The frame's 8-bit sRGB encoding by table (`raster.finish`) gives the level that
`raster.encode_srgb` computes with libm, for every value tried: a stride through all float32
in [0, 1], a band of neighbours around every level's threshold, and values out of range."""

import numpy as np
import taichi as ti

import render
from render.camera import f32
from render.raster import encode_srgb, encode_srgb_table, srgb_table


@ti.kernel
def both(x: ti.types.ndarray(dtype=f32, ndim=1), table: ti.types.ndarray(dtype=f32, ndim=1),
         direct: ti.types.ndarray(dtype=ti.i32, ndim=1),
         tabled: ti.types.ndarray(dtype=ti.i32, ndim=1)):
    for i in x:
        direct[i] = ti.cast(encode_srgb(x[i]), ti.i32)
        tabled[i] = ti.cast(encode_srgb_table(x[i], table), ti.i32)


def test_table_encoding_is_the_direct_one():
    render.init()
    table = srgb_table()
    thresholds = table.to_numpy()
    assert np.all(np.diff(thresholds) > 0.0)
    one = np.float32(1.0).view(np.int32)
    bits = [np.arange(0, one + 1, 997, dtype=np.int32)]
    for t in thresholds[1:]:
        bits.append(t.view(np.int32) + np.arange(-2000, 2001, dtype=np.int32))
    x = np.concatenate(bits).view(np.float32)
    x = np.concatenate([x, np.float32([-1.0, -1e-30, 1.0000001, 2.0, 1e30])])
    x = x.astype(np.float32)
    direct = ti.ndarray(ti.i32, (len(x),))
    tabled = ti.ndarray(ti.i32, (len(x),))
    xs = ti.ndarray(f32, (len(x),))
    xs.from_numpy(x)
    both(xs, table, direct, tabled)
    d, t = direct.to_numpy(), tabled.to_numpy()
    assert np.array_equal(d, t), x[d != t][:10]
    assert d.min() == 0 and d.max() == 255
