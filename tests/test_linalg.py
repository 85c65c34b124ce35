"""Small kernel linear algebra against numpy: the run-time-loop block product."""

import numpy as np
import pytest
import taichi as ti

from taichi_hair.rods.linalg import product

m5 = ti.types.matrix(5, 5, ti.f64)
m53 = ti.types.matrix(5, 3, ti.f64)


@ti.kernel
def _products(a: ti.types.ndarray(dtype=m5, ndim=1), b: ti.types.ndarray(dtype=m5, ndim=1),
              c: ti.types.ndarray(dtype=m53, ndim=1), out: ti.types.ndarray(dtype=m5, ndim=1),
              out53: ti.types.ndarray(dtype=m53, ndim=1)):
    for _ in range(1):
        out[0] = product(a[0], b[0], False, False)
        out[1] = product(a[0], b[0], True, False)
        out[2] = product(a[0], b[0], False, True)
        out[3] = product(a[0], b[0], True, True)
        out53[0] = product(a[0], c[0], False, False)


def test_product_is_the_matrix_product_in_each_transpose():
    rng = np.random.default_rng(1)
    a, b, c = rng.standard_normal((1, 5, 5)), rng.standard_normal((1, 5, 5)), rng.standard_normal((1, 5, 3))
    out, out53 = np.zeros((4, 5, 5)), np.zeros((1, 5, 3))
    _products(a, b, c, out, out53)
    a, b, c = a[0], b[0], c[0]
    for got, want in zip(out, (a @ b, a.T @ b, a @ b.T, a.T @ b.T)):
        assert got == pytest.approx(want, abs=1e-14)
    assert out53[0] == pytest.approx(a @ c, abs=1e-14)
