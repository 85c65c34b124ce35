"""Meshes' shadows: the filtered shadow lookup that keeps a shadow's edge straight where the
light map's texels span pixels (an analytic reference: a straight occluder edge casts a
straight edge on a floor).
"""

import numpy as np

import render
from render import Camera, Light, Lighting, Mesh, RenderSettings, ShadowSettings


def _quad(centre, half, colour=(0.6, 0.6, 0.6)):
    cx, cy, z = centre
    v = [(cx - half, cy - half, z), (cx + half, cy - half, z), (cx + half, cy + half, z),
         (cx - half, cy + half, z)]
    return Mesh(vertices=v, faces=[(0, 1, 2), (0, 2, 3)], colours=colour, specular=0.0)


def _edge_wobble(shadow_resolution):
    """A plate 0.3 m above a floor, its edge at 25 degrees to the image's columns, lit from 45
    degrees: its shadow's edge on the floor is a straight line. Returns the per-row distances
    [px] of the edge (where radiance crosses half way) from the best straight line."""
    cam = Camera(eye=(0.0, 0.0, 1.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_y=30.0,
                 width=160, height=120)
    d = np.array([np.sin(np.radians(25.0)), np.cos(np.radians(25.0)), 0.0])
    e0, back = np.array([-0.25, 0.0, 0.3]), np.array([0.3, 0.0, 0.0])
    plate = Mesh(vertices=[e0 - 0.5 * d, e0 + 0.5 * d, e0 + 0.5 * d - back, e0 - 0.5 * d - back],
                 faces=[(0, 1, 2), (0, 2, 3)], colours=(0.7, 0.7, 0.7), specular=0.0)
    lighting = Lighting(key=Light(to_light=(-1.0, 0.0, 1.0), colour=(1, 1, 1), intensity=1.0),
                        ambient_intensity=0.2)
    settings = RenderSettings(shadows=ShadowSettings(resolution=shadow_resolution))
    lum = render.render_buffers(cam, meshes=[_quad((0.0, 0.0, 0.0), 0.6, (0.7, 0.7, 0.7)), plate],
                                lighting=lighting, background=(0, 0, 0),
                                settings=settings)["rgb"].sum(axis=-1)[5:-5]
    mid = 0.5 * (lum.min() + lum.max())
    xs = []
    for row in lum:   # the shadow's right edge: the last rise through mid along the row
        j = np.nonzero((row[:-1] < mid) & (row[1:] >= mid))[0][-1]
        xs.append(j + (mid - row[j]) / (row[j + 1] - row[j]))
    y = np.arange(len(xs))
    return np.asarray(xs) - np.polyval(np.polyfit(y, xs, 1), y)


def test_shadow_edge_on_a_mesh_stays_straight_when_texels_span_pixels():
    """At 64 texels a light map texel covers about 8 pixels of the floor: a 2 x 2 lookup's edge
    follows the texel grid (measured: wobble rms 1.9 px, steps of 2.0 px between rows); the
    filtered lookup keeps it within rms 1.3 px and steps under 1 px. At 512 texels, as
    shipped, the edge is straight within 0.5 px."""
    wobble = _edge_wobble(64)
    assert np.sqrt(np.mean(wobble ** 2)) < 1.3 and np.abs(np.diff(wobble)).max() < 1.0, wobble
    assert np.abs(_edge_wobble(512)).max() < 0.5
