"""Meshes' shadows: the backdrop wall that receives the figure's shadow, and the filtered
shadow lookup that keeps a shadow's edge straight where the light map's texels span pixels.

Expected values are analytic: Lambert radiance of a matte wall, a shadow's place from
projecting the occluder along the light, a straight occluder edge casting a straight edge.
"""

import numpy as np
import pytest

import render
from render import Backdrop, Camera, Light, Lighting, Mesh, RenderSettings, ShadowSettings
from render.colour import srgb_to_linear

TOP = Camera(eye=(0.0, 0.0, 1.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_y=40.0,
             width=96, height=72)
KEY_X = Lighting(key=Light(to_light=(1.0, 0.0, 1.0), colour=(1, 1, 1), intensity=1.0),
                 ambient=(1.0, 1.0, 1.0), ambient_intensity=0.1)


def _quad(centre, half, colour=(0.6, 0.6, 0.6)):
    cx, cy, z = centre
    v = [(cx - half, cy - half, z), (cx + half, cy - half, z), (cx + half, cy + half, z),
         (cx - half, cy + half, z)]
    return Mesh(vertices=v, faces=[(0, 1, 2), (0, 2, 3)], colours=colour, specular=0.0)


def _pixel(camera, point):
    x, y, _ = camera.project([point])[0]
    return int(y), int(x)


@pytest.mark.parametrize("shadows", [True, False])
def test_wall_is_lambert_lit_and_takes_the_occluders_shadow_where_the_light_casts_it(shadows):
    """A wall 0.2 m behind a 0.1 m square, light from 45 degrees towards +x: the square's
    shadow is the square moved by -0.2 m in x on the wall (radiance albedo x ambient), the
    rest of the wall albedo x (ambient + cos 45) (key radiance 1); no shadow with shadows
    off."""
    wall = Backdrop(point=(0.0, 0.0, -0.2), normal=(0.0, 0.0, 1.0), colour=(0.5, 0.5, 0.5))
    rgb = render.render_buffers(TOP, meshes=[_quad((0.0, 0.0, 0.0), 0.05)], lighting=KEY_X,
                                backdrop=wall,
                                settings=RenderSettings(shadows=ShadowSettings(enabled=shadows)))["rgb"]
    albedo = srgb_to_linear(0.5)
    lit, dark = albedo * (0.1 + np.cos(np.radians(45.0))), albedo * 0.1
    for far in [(0.3, 0.2, -0.2), (-0.2, 0.1, -0.2), (-0.08, 0.0, -0.2)]:  # off the shadow
        np.testing.assert_allclose(rgb[_pixel(TOP, far)], lit, rtol=2e-3)
    centre = rgb[_pixel(TOP, (-0.2, 0.0, -0.2))]
    np.testing.assert_allclose(centre, dark if shadows else lit, rtol=2e-3)


def test_no_backdrop_keeps_the_flat_background_and_a_bad_one_is_refused():
    rgb = render.render_buffers(TOP, meshes=[_quad((0.0, 0.0, 0.0), 0.05)], lighting=KEY_X,
                                background=(0.5, 0.5, 0.5))["rgb"]
    np.testing.assert_allclose(rgb[_pixel(TOP, (-0.2, 0.0, -0.2))], srgb_to_linear(0.5), rtol=1e-5)
    with pytest.raises(ValueError, match="normal"):
        Backdrop(point=(0, 0, 0), normal=(0, 0, 0))
    with pytest.raises(ValueError, match="backdrop"):
        render.render_frame(TOP, backdrop=(0, 0, 1))


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


def test_framing_measure_counts_the_figure_not_the_lit_wall_or_its_shadow():
    """A sphere (radius 0.08 m, 1 m from the camera) and a hair rising from it to y = 0.15 m,
    in front of the lit wall that takes their shadow (the light from +y: the shadow falls down
    the frame): the rows the coverage mask marks span
    the projection's rows (the hair's tip at y = 0.15 m to the sphere's silhouette, tangent
    cone half-angle asin(r / d), below the centre) within a pixel and a half; the frame's own
    pixels read off the top-left one would count the wall's shading and the shadow too."""
    from render.bench import sphere_mesh
    from render.contact import subject_fraction
    wall = Backdrop(point=(0.0, 0.0, -0.2), normal=(0.0, 0.0, 1.0), colour=(0.5, 0.5, 0.5))
    hair = render.Hair(points=[np.array([[0.0, 0.07, 0.0], [0.0, 0.11, 0.0], [0.0, 0.15, 0.0]])],
                       colours=(0.3, 0.2, 0.1), widths=2e-3)
    b = render.render_buffers(TOP, meshes=[sphere_mesh(radius=0.08)], hair=hair, backdrop=wall,
                              lights=[render.DirectionalLight((-0.3, -1.0, -1.0), (3.0, 3.0, 3.0)),
                                      render.AmbientLight((0.3, 0.3, 0.3))])
    f = 0.5 * TOP.height / np.tan(np.radians(0.5 * TOP.fov_y))     # focal length [px]
    top = 0.5 * TOP.height - f * 0.15                               # the hair's tip
    bottom = 0.5 * TOP.height + f * np.tan(np.arcsin(0.08 / 1.0))   # the sphere's silhouette
    mask = np.rint(255.0 * b["coverage"]).astype(np.uint8)
    assert subject_fraction(b["image"], mask=mask) * TOP.height == pytest.approx(bottom - top, abs=1.5)
    assert b["coverage"].min() == 0.0 and b["coverage"].max() == pytest.approx(1.0)
    # the shadow, 0.2 m further down the wall, read as subject from the frame's pixels alone
    assert subject_fraction(b["image"]) * TOP.height > bottom - top + 10.0


# -- the frame writer's side ------------------------------------------------------------------

def test_frame_writer_wall_faces_the_camera_behind_its_target():
    from taichi_hair.app.runner import WALL_DISTANCE, FrameWriter, Shot
    shot = Shot(eye=(0.3, 1.0, 0.2), target=(0.0, 0.0, 0.1))
    writer = FrameWriter.__new__(FrameWriter)
    writer.shot, writer.render = shot, render
    camera = Camera(eye=shot.eye, target=shot.target, up=(0.0, 0.0, 1.0))
    wall = writer.wall(camera)
    level = np.array([0.3, 1.0, 0.0]) / np.hypot(0.3, 1.0)
    np.testing.assert_allclose(wall.normal, level, atol=1e-12)   # vertical, towards the eye
    assert np.dot(np.asarray(shot.target) - wall.point, level) == pytest.approx(WALL_DISTANCE)
    writer.shot = Shot(eye=shot.eye, target=shot.target, backdrop="plain")
    assert writer.wall(camera) is None
    with pytest.raises(ValueError, match="backdrop"):
        Shot(backdrop="studio")


def test_the_bust_base_has_its_own_vertices_so_the_sides_normals_stay_the_sides():
    """The default bust: its lowest side ring's smooth normals point sideways (the surface there
    is within a few degrees of vertical) once the flat base is split off, and the base's
    normals point straight down; sharing the base's vertices tilts the ring's normals down."""
    from taichi_hair.app.figure import hard_base
    from taichi_hair.world.bust import BASE, default_bust
    from render.geometry import vertex_normals
    v, f = default_bust()
    split = hard_base(v, f)
    shared, own = vertex_normals(v, f), vertex_normals(split["vertices"], split["faces"])
    ring = np.nonzero(np.abs(v[:, 2] - BASE) < 1e-12)[0]
    ring = ring[ring < len(v) - 2]          # not the base's centre (default_bust: the last two)
    assert np.abs(own[ring, 2]).max() < 0.2
    assert np.abs(shared[ring, 2]).min() > 0.5
    copies = np.arange(len(v), len(split["vertices"]))
    np.testing.assert_allclose(own[copies, 2], -1.0, atol=1e-9)
    assert len(copies) == len(ring) + 1


def test_the_bust_takes_the_neck_capsules_normals_at_their_seam():
    """The default bust where the neck capsule enters it: the bust's smooth normals there are
    tilted well away from the capsule's (the neck widens below the capsule: a brightness step
    when shaded); the drawn normals match the capsule's analytic normal (radial from its axis)
    within 2 degrees at the seam, turn back to the bust's own over SEAM_BAND, and are the
    bust's own beyond it."""
    from render.geometry import vertex_normals
    from taichi_hair.app.figure import SEAM_BAND, capsule_normals, hard_base, seam_normals
    from taichi_hair.world.bust import default_bust
    from taichi_hair.world.headmesh import NECK_CAPSULE
    drawn = hard_base(*default_bust())
    v = drawn["vertices"]
    smooth = vertex_normals(v, drawn["faces"])
    blended = seam_normals(v, smooth, [NECK_CAPSULE])
    p0, p1, r = (np.asarray(NECK_CAPSULE[0]), np.asarray(NECK_CAPSULE[1]), NECK_CAPSULE[2])
    t = np.clip((v - p0) @ (p1 - p0) / ((p1 - p0) @ (p1 - p0)), 0.0, 1.0)
    radial = v - (p0 + t[:, None] * (p1 - p0))
    outside = np.linalg.norm(radial, axis=1) - r
    radial /= np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-12)   # the top disc's centre is on the axis
    towards, out = capsule_normals(v, NECK_CAPSULE)
    np.testing.assert_allclose(out, outside, atol=1e-12)
    np.testing.assert_allclose(towards, radial, atol=1e-12)
    seam = np.abs(outside) < 1e-3
    assert seam.sum() >= 48
    angle = lambda a, b: np.degrees(np.arccos(np.clip((a * b).sum(axis=1), -1.0, 1.0)))
    assert angle(smooth[seam], radial[seam]).min() > 10.0
    assert angle(blended[seam], radial[seam]).max() < 2.0
    far = outside > SEAM_BAND
    np.testing.assert_allclose(blended[far], smooth[far], atol=1e-12)
    used = np.unique(drawn["faces"])
    np.testing.assert_allclose(np.linalg.norm(blended[used], axis=1), 1.0, atol=1e-12)


def test_where_two_meshes_cross_the_line_is_antialiased():
    """A red and a blue square crossing at 40 degrees (depth continuous across the line they
    meet on): one sample per pixel against 4 x 4 supersampled. Without telling the meshes apart
    the crossing line is all red or all blue per pixel (measured: 38 pixels off by > 0.1, up to
    0.375); with it, the line's pixels blend as the supersampled frame does."""
    flat = Lighting(key=Light(intensity=0.0), ambient=(1.0, 1.0, 1.0), ambient_intensity=1.0)
    # the camera rolled, so the crossing line (x = 0) runs slanted across the pixels
    cam = Camera(eye=(0.0, 0.0, 1.0), target=(0.0, 0.0, 0.0), up=(0.4, 1.0, 0.0), fov_y=30.0,
                 width=64, height=48)
    t = np.radians(40.0)
    tilt = lambda x, y: (x * np.cos(t), y, x * np.sin(t))    # the blue square, turned about y
    blue = Mesh(vertices=[tilt(-0.5, -0.5), tilt(0.5, -0.5), tilt(0.5, 0.5), tilt(-0.5, 0.5)],
                faces=[(0, 1, 2), (0, 2, 3)], colours=(0.0, 0.0, 1.0), specular=0.0)
    red = _quad((0.0, 0.0, 0.0), 0.5, (1.0, 0.0, 0.0))
    rgb = {s: render.render_buffers(cam, meshes=[red, blue], lighting=flat,
                                    settings=RenderSettings(supersample=s))["rgb"] for s in (1, 4)}
    d = np.abs(rgb[1] - rgb[4]).max(axis=-1)
    assert d.max() < 0.25 and (d > 0.1).sum() < 8, (d.max(), (d > 0.1).sum())
