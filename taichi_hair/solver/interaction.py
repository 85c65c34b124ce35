"""Hair-hair interaction on a grid (Petrovic et al. 2005; McAdams et al. 2009): node mass and
momentum are splatted to a regular grid each step; where the hair density exceeds its groomed
value, a pressure-like repulsion pushes nodes down the density gradient (keeps the hair's
volume), and every node's velocity relaxes toward the grid velocity (hair-hair friction: hair
moves as a continuum). Chosen over guide-guide segment collisions because guides stand for
many hairs: a guide is a sample of a continuum, not a fibre that should stop exactly at its
neighbours, and the grid costs O(nodes) without pair searches.
"""

import math

import numpy as np
import taichi as ti

from ..rods import arrays
from ..rods.arrays import Ints1, Points2, Scalars2, Scalars3, Vec3s1, Vec3s2, point, vec3
from ..rods.linalg import corner_factors, corner_signs, grid_cell
from ..world.forces import HairInteraction

Vec3s3 = ti.types.ndarray(dtype=vec3, ndim=3)


@ti.func
def cell_weights(x, origin, spacing):
    """The trilinear cell of point x [m] on a grid of cells whose centres sit at
    origin + (i + 1/2) spacing."""
    return grid_cell((x - origin) / spacing - 0.5)


@ti.func
def inside(grid: ti.template(), i, j, k):
    return 0 <= i < grid.shape[0] and 0 <= j < grid.shape[1] and 0 <= k < grid.shape[2]


@ti.kernel
def clear_grid(density: Scalars3, momentum: Vec3s3):
    for i, j, k in ti.ndrange(density.shape[0], density.shape[1], density.shape[2]):
        density[i, j, k] = 0.0
        momentum[i, j, k] = vec3(0.0)


@ti.kernel
def splat(node_count: Ints1, mass: Scalars2, x: Points2, v: Vec3s2, frame: Vec3s1,
          density: Scalars3, momentum: Vec3s3):
    """density += m w / cell volume, momentum += m v w / cell volume (trilinear w), frame =
    (origin [m], (spacing [m], 0, 0)). One thread per node."""
    spacing = frame[1][0]
    inv_volume = 1.0 / (spacing * spacing * spacing)
    for s, i in ti.ndrange(x.shape[0], x.shape[1]):
        if i < node_count[s]:
            base, f = cell_weights(point(x, s, i), frame[0], spacing)
            for c in ti.static(ti.grouped(ti.ndrange(2, 2, 2))):
                factors = corner_factors(c, f)
                w = factors[0] * factors[1] * factors[2]
                cell = base + c
                if inside(density, cell[0], cell[1], cell[2]):
                    density[cell[0], cell[1], cell[2]] += w * mass[s, i] * inv_volume
                    momentum[cell[0], cell[1], cell[2]] += w * mass[s, i] * inv_volume * v[s, i]


@ti.kernel
def apply_interaction(node_count: Ints1, inv_mass: Scalars2, mass: Scalars2, x: Points2, v: Vec3s2,
                      frame: Vec3s1, density: Scalars3, momentum: Vec3s3, max_density: float,
                      repulsion: float, blend: float, force: Vec3s2):
    """Velocity smoothing toward the grid velocity (fraction `blend` this step) and the
    density repulsion force [N] on free nodes. One thread per node."""
    spacing = frame[1][0]
    for s, i in ti.ndrange(x.shape[0], x.shape[1]):
        if i < node_count[s] and inv_mass[s, i] > 0.0:
            base, f = cell_weights(point(x, s, i), frame[0], spacing)
            rho = 0.0
            p = vec3(0.0)
            grad = vec3(0.0)
            for c in ti.static(ti.grouped(ti.ndrange(2, 2, 2))):
                w3 = corner_factors(c, f)
                sign = corner_signs(c)
                cell = base + c
                if inside(density, cell[0], cell[1], cell[2]):
                    value = density[cell[0], cell[1], cell[2]]
                    rho += w3[0] * w3[1] * w3[2] * value
                    p += w3[0] * w3[1] * w3[2] * momentum[cell[0], cell[1], cell[2]]
                    grad += value * sign * vec3(w3[1] * w3[2], w3[0] * w3[2], w3[0] * w3[1]) / spacing
            if rho > 0.0:
                v[s, i] += blend * (p / rho - v[s, i])
            if rho > max_density:
                force[s, i] -= repulsion * mass[s, i] * grad / max_density


class InteractionGrid:
    """The grid arrays of one simulator and the stage that uses them."""

    def __init__(self, settings: HairInteraction, groom, model, state, head_translation):
        self.settings = settings
        reach = np.linalg.norm(groom.positions[:, 0] - head_translation, axis=1).max() + groom.lengths().max()
        self.half_extent = reach + 2 * settings.cell_size
        n = int(math.ceil(2 * self.half_extent / settings.cell_size))
        if n**3 > 64**3 * 8:
            raise ValueError(f"hair_interaction.cell_size {settings.cell_size:g} m makes a {n}^3 grid for "
                             f"hair reaching {reach:.2f} m; use a larger cell_size")
        self.shape = (n, n, n)
        self.density = arrays.scalars(self.shape)
        self.momentum = arrays.vectors(3, self.shape)
        self.frame = arrays.vectors(3, (2,))
        self._set_frame(head_translation)
        self.max_density = settings.max_density or self._groomed_density(model, state)

    def _set_frame(self, translation):
        origin = np.asarray(translation, dtype=np.float64) - self.half_extent
        self.frame.from_numpy(np.array([origin, [self.settings.cell_size, 0.0, 0.0]]).astype(arrays.np_float()))

    def _splat(self, model, state):
        clear_grid(self.density, self.momentum)
        splat(model.node_count, model.mass, state.x, state.v, self.frame, self.density, self.momentum)

    def _groomed_density(self, model, state):
        self._splat(model, state)
        values = self.density.to_numpy()
        occupied = values[values > 0]
        return float(np.percentile(occupied, 90)) if len(occupied) else 1.0

    def stage(self, model, state, control, h):
        """Splat, then smooth velocities and add repulsion forces (after the other forces)."""
        self._set_frame(control.head.to_numpy()[1, 3])
        self._splat(model, state)
        blend = 1.0 - math.exp(-self.settings.friction * h)
        apply_interaction(model.node_count, model.inv_mass, model.mass, state.x, state.v, self.frame,
                          self.density, self.momentum, self.max_density, self.settings.repulsion,
                          blend, state.force)
