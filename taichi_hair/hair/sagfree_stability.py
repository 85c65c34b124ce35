"""Whether a sag-free balance (taichi_hair.hair.sagfree) is a minimum of the energy or a saddle
the strand leaves at once: the smallest eigenvalues of the Hessians over the material angles and
over the positions, by central differences of the simulator's own forces."""

import numpy as np

from ..runtime import precision


def twist_hessian_min(groom, sim, layout):
    """Smallest eigenvalue [S] of d^2E/dtheta^2 over the free edges (0..n-2), relative to the
    twist stiffness GJ / l. The Hessian is tridiagonal (an edge's angle meets its neighbours' in
    one twist and one bending term), so three central differences of dE/dtheta, each moving every
    third edge of every strand, give all of it."""
    step = 1e-5 if precision() == "float64" else 1e-2  # [rad]
    theta = sim.material_angles()
    s_count, edges = theta.shape
    hess = np.zeros((s_count, edges, 3))  # [sub, diag, super] of row k
    for colour in range(3):
        moved = np.zeros(edges, dtype=bool)
        moved[colour::3] = True
        grads = []
        for sign in (1.0, -1.0):
            sim.set_material_angles(theta + sign * step * moved[None, :])
            grads.append(sim.theta_gradient().astype(np.float64))
        d = (grads[0] - grads[1]) / (2 * step)  # column j of H lands on rows j-1, j, j+1
        for k in range(edges):
            for offset, slot in ((-1, 0), (0, 1), (1, 2)):
                if 0 <= k + offset < edges and moved[k + offset]:
                    hess[:, k, slot] = d[:, k]
    sim.set_material_angles(theta)
    voronoi = sim.model.voronoi.to_numpy().astype(np.float64)
    gj = sim.model.stiffness.to_numpy()[:, 2].astype(np.float64)
    out = np.zeros(s_count)
    for s, n in enumerate(groom.node_counts):
        free = layout.free_edges(n)
        block = hess[s, free]  # rows of the free edges; their sub/super entries couple free edges
        if not len(block):
            out[s] = 1.0
            continue
        h = np.diag(block[:, 1]) + np.diag(block[1:, 0], -1) + np.diag(block[:-1, 2], 1)
        scale = gj[s] / voronoi[s, free].mean()  # edge j's twist node j: l_0 is half the first edge
        out[s] = np.linalg.eigvalsh(0.5 * (h + h.T))[0] / scale
    return out


def position_hessian_min(groom, sim, multipliers, contacts, g, layout):
    """Smallest eigenvalue [S] of the energy's Hessian on the constraint manifold at the groomed
    pose (angles held), in units of the strand's mean nodal weight over its mean segment
    length: negative means the balance is a saddle, and
    the strand leaves it (measured: an e-fold every ~7 ms for hair leaving the scalp sideways
    and bending down, whatever the time step). H = -dF/dx (central differences of the
    simulator's force, one node coordinate of every strand at a time) + sum_j T_j d^2|e_j|/dx^2,
    T_j the balance's tensions, projected on the motions that keep the edge lengths and the
    contact nodes' normal offsets."""
    x0 = sim.positions().astype(np.float64)
    s_count, n_max = x0.shape[:2]
    lengths = sim.model.rest_length.to_numpy()
    step = (1e-6 if precision() == "float64" else 1e-3) * float(np.median(lengths[lengths > 0]))
    hess = np.zeros((s_count, n_max, 3, n_max, 3))
    for i in range(n_max)[layout.free_nodes(n_max)]:
        for c in range(3):
            forces = []
            for sign in (1.0, -1.0):
                x = x0.copy()
                x[:, i, c] += sign * step
                sim.set_positions(x)
                forces.append(sim.elastic_forces().astype(np.float64))
            hess[:, :, :, i, c] = -(forces[0] - forces[1]) / (2.0 * step)
    sim.set_positions(x0)
    out = np.ones(s_count)
    held = layout.held
    for s, n in enumerate(groom.node_counts):
        free = layout.free_nodes(n)
        m = 3 * layout.n_free(n)
        h = hess[s, free, :, free, :].reshape(m, m)
        h = 0.5 * (h + h.T)
        e = np.diff(x0[s, :n], axis=0)
        norm = np.linalg.norm(e, axis=1)
        t = e / norm[:, None]
        rows = []
        for col, j in enumerate(layout.tension_edges(n)):  # edge j joins nodes j and j+1
            block = multipliers[s][col] * (np.eye(3) - np.outer(t[j], t[j])) / norm[j]
            row = np.zeros(m)
            for node, sign in ((j, -1.0), (j + 1, 1.0)):
                if node >= held:
                    k = 3 * (node - held)
                    row[k:k + 3] = sign * t[j]
            rows.append(row)
            a, b = 3 * (j - held), 3 * (j + 1 - held)
            h[b:b + 3, b:b + 3] += block
            if j >= held:
                h[a:a + 3, a:a + 3] += block
                h[a:a + 3, b:b + 3] -= block
                h[b:b + 3, a:a + 3] -= block
        for node, normal in zip(*contacts[s]):
            row = np.zeros(m)
            row[3 * (node - held):3 * (node - held) + 3] = normal
            rows.append(row)
        _, sv, vt = np.linalg.svd(np.array(rows))
        rank = int(np.count_nonzero(sv > 1e-10 * sv.max()))
        basis = vt[rank:].T
        eig = np.linalg.eigvalsh(basis.T @ h @ basis)
        mass = sim.model.mass.to_numpy()[s, free].mean()
        out[s] = eig[0] / max(mass * np.linalg.norm(g) / norm.mean(), 1e-300)
    return out
