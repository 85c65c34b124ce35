"""Reference and material frames of every edge, and curvature binormals of every node.

Bishop frame: u^0 of the root edge is the head-carried reference u_ref (the clamp's material
direction) moved by parallel transport from t_ref to the current root tangent, then
u^j = P_{t^{j-1} -> t^j}(u^{j-1}), v^j = t^j x u^j.
Material frame: m1 = cos(theta) u + sin(theta) v, m2 = -sin(theta) u + cos(theta) v
(docs/model.md; the seed thesis' eq. 3.12 / 3.18 print the sign of m2 wrong, 3.26 is right).
"""

import taichi as ti

from .arrays import Ints1, Points2, Scalars2, Vec3s1, Vec3s2, edge, vec3


@ti.func
def parallel_transport(w, a, b):
    """Rotate vector w by the rotation taking unit tangent a to unit tangent b about a x b."""
    axis = a.cross(b)
    c = a.dot(b)
    result = w
    if 1.0 + c > 1e-6:
        result = c * w + axis.cross(w) + axis.dot(w) * axis / (1.0 + c)
    else:
        # a and b (nearly) opposite: the minimal rotation is ill-defined; turn by pi about an
        # axis perpendicular to a (growing strands never get here: grooms reject such folds)
        helper = vec3(1.0, 0.0, 0.0)
        if ti.abs(a.x) > 0.9:
            helper = vec3(0.0, 1.0, 0.0)
        n = a.cross(helper).normalized()
        result = 2.0 * n.dot(w) * n - w
    return result


@ti.func
def curvature_binormal(e0, e1):
    """kb = 2 e0 x e1 / (|e0||e1| + e0.e1) [1] for consecutive edges e0, e1 [m]."""
    return 2.0 * e0.cross(e1) / (e0.norm() * e1.norm() + e0.dot(e1))


@ti.func
def material_directors(u, v, theta):
    c = ti.cos(theta)
    s = ti.sin(theta)
    return c * u + s * v, -s * u + c * v


@ti.func
def strand_frames(s, clamp: ti.template(), x: ti.template(), node_count: ti.template(),
                  root_t: ti.template(), root_u: ti.template(), theta: ti.template(),
                  bishop_u: ti.template(), bishop_v: ti.template(), m1: ti.template(),
                  m2: ti.template(), kb: ti.template()):
    """Strand s's Bishop frames, material frames and curvature binormals (see update_frames)."""
    n = node_count[s]
    t_prev = edge(x, s, 0, 1).normalized()
    u = parallel_transport(root_u[s], root_t[s], t_prev)
    kb[s, 0] = vec3(0.0)
    if ti.static(clamp):  # node 0 bends between the clamp (root_t) and edge 0
        kb[s, 0] = curvature_binormal(root_t[s], edge(x, s, 0, 1))
    for j in range(n - 1):
        e = edge(x, s, j, j + 1)
        t = e.normalized()
        if j > 0:
            u = parallel_transport(u, t_prev, t)
            kb[s, j] = curvature_binormal(edge(x, s, j - 1, j), e)
        # re-orthonormalise so rounding cannot accumulate along long strands
        u = (u - u.dot(t) * t).normalized()
        v = t.cross(u)
        bishop_u[s, j] = u
        bishop_v[s, j] = v
        m1[s, j], m2[s, j] = material_directors(u, v, theta[s, j])
        t_prev = t
    kb[s, n - 1] = vec3(0.0)


@ti.kernel
def update_frames(clamp: ti.template(), x: Points2, node_count: Ints1, root_t: Vec3s1,
                  root_u: Vec3s1, theta: Scalars2, bishop_u: Vec3s2, bishop_v: Vec3s2, m1: Vec3s2,
                  m2: Vec3s2, kb: Vec3s2):
    """Bishop frames (u, v), material frames (m1, m2) of every edge [S, N-1] and curvature
    binormals kb of every node [S, N] from positions x [m]: zero at the tip, and at the root
    unless it is clamped (clamp: kb_0 between the clamp direction root_t and edge 0).
    One thread per strand: the parallel transport sweeps from root to tip."""
    for s in range(x.shape[0]):
        strand_frames(s, clamp, x, node_count, root_t, root_u, theta, bishop_u, bishop_v, m1, m2, kb)


@ti.func
def strand_material_frames(s, node_count: ti.template(), theta: ti.template(), bishop_u: ti.template(),
                           bishop_v: ti.template(), m1: ti.template(), m2: ti.template()):
    for j in range(node_count[s] - 1):
        m1[s, j], m2[s, j] = material_directors(bishop_u[s, j], bishop_v[s, j], theta[s, j])


@ti.kernel
def update_material_frames(node_count: Ints1, theta: Scalars2, bishop_u: Vec3s2, bishop_v: Vec3s2,
                           m1: Vec3s2, m2: Vec3s2):
    """m1, m2 [S, N-1] from the Bishop frames and material angles theta [rad]. One thread per strand."""
    for s in range(theta.shape[0]):
        strand_material_frames(s, node_count, theta, bishop_u, bishop_v, m1, m2)
