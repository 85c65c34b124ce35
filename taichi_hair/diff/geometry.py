"""Taichi functions of the differentiable step (docs/differentiable.md): head poses from pose
parameters, the material views of a curvature binormal and their angle derivatives.

Every function here is smooth where it is used and written for Taichi's reverse-mode autodiff
(no global writes)."""

import taichi as ti

from ..rods.frames import material_directors

# below this squared angle [rad^2] the rotation's coefficients come from their series, so the
# gradient at a zero rotation (the rest pose) is finite
SMALL_ANGLE_SQ = 1e-8


@ti.func
def rotation_from_vector(k):
    """Rotation matrix of rotation vector k [rad] (axis times angle), Rodrigues' formula."""
    a2 = k.dot(k)
    # the exact coefficients at an angle kept away from 0 and their series below, chosen by
    # select (no branch: reverse mode differentiates both with finite values)
    a = ti.sqrt(ti.max(a2, SMALL_ANGLE_SQ))
    small = a2 < SMALL_ANGLE_SQ
    sin_over = ti.select(small, 1.0 - a2 / 6.0 + a2 * a2 / 120.0, ti.sin(a) / a)
    cos_over = ti.select(small, 0.5 - a2 / 24.0 + a2 * a2 / 720.0, (1.0 - ti.cos(a)) / (a * a))
    # I + sin_over [k]x + cos_over [k]x^2, with [k]x^2 = k k^T - |k|^2 I written out
    return ti.Matrix([[1.0 + cos_over * (k.x * k.x - a2), cos_over * k.x * k.y - sin_over * k.z,
                       cos_over * k.x * k.z + sin_over * k.y],
                      [cos_over * k.y * k.x + sin_over * k.z, 1.0 + cos_over * (k.y * k.y - a2),
                       cos_over * k.y * k.z - sin_over * k.x],
                      [cos_over * k.z * k.x - sin_over * k.y, cos_over * k.z * k.y + sin_over * k.x,
                       1.0 + cos_over * (k.z * k.z - a2)]])


@ti.func
def rotated(r, v):
    """r v for a 3x3 matrix r, written out (Taichi 1.7's matrix product accumulates in a local
    its reverse mode reads before writing, with a warning per element)."""
    return ti.Vector([r[0, 0] * v[0] + r[0, 1] * v[1] + r[0, 2] * v[2],
                      r[1, 0] * v[0] + r[1, 1] * v[1] + r[1, 2] * v[2],
                      r[2, 0] * v[0] + r[2, 1] * v[1] + r[2, 2] * v[2]])


@ti.func
def views(kb, u, t, angle):
    """Material curvature w = (kb . m2, -kb . m1) of binormal kb seen from an edge with Bishop
    vector u, tangent t and material angle `angle`, and the directors (m1, m2)."""
    m1, m2 = material_directors(u, t.cross(u), angle)
    return ti.Vector([kb.dot(m2), -kb.dot(m1)]), m1, m2


@ti.func
def clamp_view(kb, d1, d2):
    """Material curvature (kb . d2, -kb . d1) of binormal kb seen from the clamp's directors."""
    return ti.Vector([kb.dot(d2), -kb.dot(d1)])


@ti.func
def view_angle_terms(w, rest, ei1, ei2, inv_2l):
    """Bending energy of one view and its first and second derivatives in the edge's angle:
    E = (w - rest)^T B (w - rest) / (4 l), dw/dangle = (w2, -w1) (inv_2l = 1 / (2 l))."""
    d = w - rest
    dw = ti.Vector([w[1], -w[0]])
    energy = 0.5 * inv_2l * (ei1 * d[0] * d[0] + ei2 * d[1] * d[1])
    grad = inv_2l * (ei1 * d[0] * dw[0] + ei2 * d[1] * dw[1])
    hess = inv_2l * (ei1 * (dw[0] * dw[0] - d[0] * w[0]) + ei2 * (dw[1] * dw[1] - d[1] * w[1]))
    return energy, grad, hess


@ti.func
def view_kb_gradient(w, rest, m1, m2, ei1, ei2, inv_2l):
    """d E / d kb of one view (E as in view_angle_terms): w1 = kb . m2, w2 = -kb . m1."""
    d = w - rest
    return inv_2l * (ei1 * d[0] * m2 - ei2 * d[1] * m1)
