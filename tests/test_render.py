"""Offscreen renderer: depth order, coverage, shading, shadows, meshes, video.

Small frames (64 x 48 unless stated) on the CPU. Colour checks use flat lighting (ambient 1,
no key light, no highlights) where the expected linear colour is then exactly the albedo.
"""

import numpy as np
import pytest
import taichi as ti

import render
from render import (Camera, Hair, HairShading, Light, Lighting, Mesh, RenderSettings,
                    ShadowSettings, Turntable)
from render.colour import srgb_to_linear

W, H = 64, 48
FRONT = Camera(eye=(0.0, 0.0, 1.0), target=(0.0, 0.0, 0.0), fov_y=40.0, width=W, height=H)
BACK = Camera(eye=(0.0, 0.0, -1.0), target=(0.0, 0.0, 0.0), fov_y=40.0, width=W, height=H)
FLAT = Lighting(key=Light(intensity=0.0), ambient=(1.0, 1.0, 1.0), ambient_intensity=1.0)
NO_SPEC = HairShading(primary_strength=0.0, secondary_strength=0.0)
RED, BLUE = (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)


def flat_settings(layers=4, shadows=False, compositor="tiles", **kw):
    return RenderSettings(layers=layers, compositor=compositor, hair_shading=NO_SPEC,
                          hair_model="kajiya_kay",
                          shadows=ShadowSettings(enabled=shadows), **kw)


def px_width(camera, depth, pixels):
    """World width [m] that projects to `pixels` at `depth` [m]."""
    return pixels * camera.metres_per_pixel(depth)


def line(p0, p1, n=5):
    return np.linspace(p0, p1, n)


def crossing(z_red, z_blue, width_px=4.0):
    """A red horizontal and a blue vertical strand crossing on the view axis."""
    pts = np.stack([line((-0.2, 0.0, z_red), (0.2, 0.0, z_red)),
                    line((0.0, -0.2, z_blue), (0.0, 0.2, z_blue))])
    w = px_width(FRONT, 1.0, width_px)
    return Hair(points=pts, colours=np.array([RED, BLUE]), widths=w)


# -- depth order ----------------------------------------------------------------------------

@pytest.mark.parametrize("compositor, layers", [("tiles", 4), ("kbuffer", 1), ("kbuffer", 4)])
@pytest.mark.parametrize("camera, z_red, z_blue, winner", [
    (FRONT, 0.05, -0.05, RED), (FRONT, -0.05, 0.05, BLUE),
    (BACK, 0.05, -0.05, BLUE), (BACK, -0.05, 0.05, RED)])
def test_nearer_strand_wins_at_crossing(compositor, layers, camera, z_red, z_blue, winner):
    out = render.render_buffers(camera, hair=crossing(z_red, z_blue), lighting=FLAT,
                                settings=flat_settings(layers, compositor=compositor))
    centre = out["rgb"][H // 2 - 1:H // 2 + 1, W // 2 - 1:W // 2 + 1].reshape(-1, 3)
    np.testing.assert_allclose(centre, np.tile(winner, (4, 1)), atol=0.02)
    # both strands are drawn away from the crossing
    assert out["rgb"][H // 2, W // 2 - 8, 0] > 0.9 and out["rgb"][H // 2 - 8, W // 2, 2] > 0.9


def test_tiles_blend_front_to_back_like_an_exact_sort():
    """Dense synthetic hair: the tiled compositor against the k-buffer with K = 16 exact
    layers (the tail barely matters there): same coverage, nearly the same colour."""
    from render.bench import sphere_mesh, synthetic_hair
    hair = synthetic_hair(1500, 16, width=4e-4)
    cam = Camera(eye=(0.05, 0.02, 0.62), target=(0.0, -0.06, 0.0), fov_y=40.0, width=96, height=72)
    out = {c: render.render_buffers(cam, hair=hair, meshes=[sphere_mesh()],
                                    settings=RenderSettings(compositor=c, layers=16))
           for c in ("tiles", "kbuffer")}
    assert out["tiles"]["alpha"].max() > 0.99 and (out["tiles"]["alpha"] > 0.5).mean() > 0.1
    np.testing.assert_allclose(out["tiles"]["alpha"], out["kbuffer"]["alpha"], atol=2e-3)
    diff = np.abs(out["tiles"]["rgb"] - out["kbuffer"]["rgb"])
    assert diff.mean() < 2e-3 and np.percentile(diff, 99) < 0.02, (diff.mean(), diff.max())


def test_strand_lod_keeps_coverage_and_colour():
    """Level of detail: half or a quarter of the strands, widened, against the full render
    of sub-pixel hair: the same hair coverage and mean colour within a few per cent."""
    from render.bench import sphere_mesh, synthetic_hair
    hair = synthetic_hair(6000, 16, width=8e-5)
    cam = Camera(eye=(0.05, 0.02, 0.62), target=(0.0, -0.06, 0.0), fov_y=40.0, width=160, height=120)
    out = {f: render.render_buffers(cam, hair=hair, meshes=[sphere_mesh()],
                                    settings=RenderSettings(strand_lod=f)) for f in (1.0, 0.5, 0.25)}
    mask = out[1.0]["alpha"] > 0.05
    assert 0.1 < out[1.0]["alpha"][mask].mean() < 0.95  # partly transparent: LOD matters
    for f in (0.5, 0.25):
        assert out[f]["alpha"][mask].mean() == pytest.approx(out[1.0]["alpha"][mask].mean(), rel=0.05)
        np.testing.assert_allclose(out[f]["rgb"][mask].mean(axis=0), out[1.0]["rgb"][mask].mean(axis=0),
                                   rtol=0.05)


def test_shading_stride_two_keeps_the_picture():
    """Shading every other vertex along the strands where they turn little (the default) and
    interpolating the rest, against shading every vertex: the same coverage to the bit,
    colours within a mean CIEDE2000 of 0.6 over the hair (dark or unshaded vertices would be
    tens), with a fifth of the vertices or more interpolated."""
    from render.bench import sphere_mesh, synthetic_hair
    from render.colour import delta_e2000, linear_to_lab, srgb_to_linear
    hair = synthetic_hair(1500, 32, width=2e-4)
    cam = Camera(eye=(0.05, 0.02, 0.62), target=(0.0, -0.06, 0.0), fov_y=40.0, width=320, height=240)
    lights = render.three_point_lights((0.05, 0.02, 0.62), (0.0, 1.0, 0.0))
    out = {}
    for k in (1, 2):
        out[k] = render.render_buffers(cam, hair=hair, meshes=[sphere_mesh()], lights=lights,
                                       settings=RenderSettings(shading_stride=k))
    mark = render.runtime.buffer("hair_mark", ti.i32, (len(hair.vertices),)).to_numpy()
    assert (mark < 0).mean() > 0.15
    np.testing.assert_array_equal(out[1]["alpha"], out[2]["alpha"])
    hair_px = out[1]["alpha"] > 0.2
    assert hair_px.mean() > 0.05
    lab = {k: linear_to_lab(srgb_to_linear(out[k]["image"][hair_px] / 255.0)) for k in (1, 2)}
    assert delta_e2000(lab[1], lab[2]).mean() < 0.6


def test_shading_stride_takes_its_parity_along_each_strand():
    """Straight strands of 7 and 2 vertices in turn, one after another in the buffer (the
    long ones starting at even and odd indices in turn) and end to end in space, in rows (so
    that no bend tells one strand from the next), of alternating colours: at shading stride 2
    exactly the interior vertices at odd places along their own strand are interpolated (not
    a short strand's root, which a walk past a long strand's tip would reach), every strand's
    ends are shaded, the shaded vertices' colours are those of stride 1 and each interpolated
    one is its own strand's neighbours' stride-1 colours linear in arc length (a neighbour
    from the next strand, of the other colour, would be far off)."""
    counts = [7, 2] * 12
    spans = {7: np.linspace(0.0, 1.0, 7) ** 1.3 * 0.02, 2: np.array([0.0, 0.008])}  # uneven spacing
    strands, x0 = [], 0.0
    for k, n in enumerate(counts):
        if k % 6 == 0:
            x0 = -0.08
        strands.append(np.stack([x0 + spans[n], np.full(n, 0.02 * (k // 6) - 0.03), np.zeros(n)], axis=1))
        x0 += spans[n][-1] + 0.005
    colours = [(0.6, 0.35, 0.2) if k % 2 else (0.1, 0.1, 0.12) for k in range(len(counts))]
    hair = Hair(points=strands, colours=colours, widths=3e-4)
    cam = Camera(eye=(0.0, 0.0, 0.4), target=(0.0, 0.0, 0.0), fov_y=40.0, width=96, height=72)
    nv = sum(counts)
    rgba, mark = {}, None
    for k in (1, 2):
        render.render_buffers(cam, hair=hair, settings=RenderSettings(shading_stride=k, compositor="kbuffer"))
        rgba[k] = render.runtime.buffer("hair_rgba", render.camera.vec4f, (nv,), 4).to_numpy()
        if k == 2:
            mark = render.runtime.buffer("hair_mark", ti.i32, (nv,)).to_numpy()
    place = np.concatenate([np.arange(n) for n in counts])
    last = np.concatenate([np.arange(n) == n - 1 for n in counts])
    interpolated = mark < 0
    np.testing.assert_array_equal(interpolated, (place % 2 == 1) & ~last)
    np.testing.assert_array_equal(rgba[2][~interpolated], rgba[1][~interpolated])
    x = hair.vertices
    i = np.nonzero(interpolated)[0]
    la, lb = np.linalg.norm(x[i] - x[i - 1], axis=1), np.linalg.norm(x[i + 1] - x[i], axis=1)
    s = (la / (la + lb))[:, None]
    np.testing.assert_allclose(rgba[2][i], (1 - s) * rgba[1][i - 1] + s * rgba[1][i + 1], rtol=1e-5)


def test_spatial_order_draws_the_same_hair(monkeypatch):
    """Large grooms are drawn with their strands in a spatial order (`Hair.subset`): the
    light reaching each vertex comes back in the Hair's own order, the same to the bit
    (the opacity map's sums do not depend on the order), and the frame keeps its coverage and
    colours (only which vertices the shading stride interpolates changes with the order)."""
    import render.geometry
    from render.bench import sphere_mesh, synthetic_hair
    from render.colour import delta_e2000, linear_to_lab, srgb_to_linear
    hair = synthetic_hair(1500, 32, width=2e-4, seed=3)
    cam = Camera(eye=(0.05, 0.02, 0.62), target=(0.0, -0.06, 0.0), fov_y=40.0, width=320, height=240)
    out, shadow, order = {}, {}, {}
    for spatial in (False, True):
        monkeypatch.setattr(render.geometry, "SPATIAL_ORDER_VERTICES", 1 if spatial else 10 ** 12)
        hair.__dict__.pop("_lod_cache", None)
        out[spatial] = render.render_buffers(cam, hair=hair, meshes=[sphere_mesh()])
        shadow[spatial] = render.hair_shadow(hair, meshes=[sphere_mesh()])
        order[spatial] = hair.subset(1.0)["order"]
    assert not np.array_equal(order[True], order[False])
    assert np.array_equal(np.sort(order[True]), order[False])
    np.testing.assert_array_equal(shadow[True], shadow[False])
    assert shadow[False].min() < 0.5   # some hair in shadow
    np.testing.assert_allclose(out[True]["alpha"], out[False]["alpha"], atol=1e-5)
    hair_px = out[False]["alpha"] > 0.2
    lab = {k: linear_to_lab(srgb_to_linear(out[k]["image"][hair_px] / 255.0)) for k in out}
    assert delta_e2000(lab[True], lab[False]).mean() < 0.6


# -- anti-aliasing ------------------------------------------------------------------------

@pytest.mark.parametrize("w", [0.3, 0.5, 1.0, 1.5, 2.0, 3.0])
def test_horizontal_line_covers_its_width_per_column(w):
    # centre line 0.3 px below a pixel row boundary: coverage must split over rows
    y = (H / 2 - (H / 2 + 0.3)) * FRONT.metres_per_pixel(1.0)
    hair = Hair(points=[line((-0.3, y, 0.0), (0.3, y, 0.0), 7)], colours=RED,
                widths=px_width(FRONT, 1.0, w))
    alpha = render.render_buffers(FRONT, hair=hair, lighting=FLAT,
                                  settings=flat_settings())["alpha"]
    columns = alpha[:, 16:W - 16].sum(axis=0)
    # box-filtered coverage: within 10 % of w in every column, joints included
    np.testing.assert_allclose(columns, w, rtol=0.10)
    # a sub-pixel fibre is a faint line, never a fully opaque pixel
    assert alpha.max() <= min(w, 1.0) + 1e-4


def test_sloped_line_coverage_scales_with_secant():
    w, slope = 1.0, np.tan(np.radians(30.0))
    hair = Hair(points=[line((-0.25, -0.25 * slope, 0.0), (0.25, 0.25 * slope, 0.0), 6)],
                colours=RED, widths=px_width(FRONT, 1.0, w))
    alpha = render.render_buffers(FRONT, hair=hair, lighting=FLAT,
                                  settings=flat_settings())["alpha"]
    columns = alpha[:, 20:W - 20].sum(axis=0)
    assert columns.mean() == pytest.approx(w / np.cos(np.radians(30.0)), rel=0.10)


# -- shading -----------------------------------------------------------------------------

def _sweep(shading, n=721):
    """Tangents in the x-z plane against a fixed light and eye; returns angles, terms, phi0
    (the angle where T is perpendicular to H)."""
    phi = np.linspace(-np.pi / 2, np.pi / 2, n)
    t = np.stack([np.cos(phi), np.zeros_like(phi), np.sin(phi)], axis=1)
    l = np.array([0.0, 0.0, 1.0])
    v = np.array([np.sin(np.radians(50.0)), 0.0, np.cos(np.radians(50.0))])
    h = (l + v) / np.linalg.norm(l + v)
    phi0 = np.arctan2(-h[0], h[2])  # T(phi0) . h = 0
    return phi, render.kajiya_kay(t, l, v, shading), phi0, t, l


def test_kajiya_kay_highlight_peaks_where_tangent_perpendicular_to_half_vector():
    phi, kk, phi0, t, l = _sweep(HairShading(primary_shift=0.0, secondary_shift=0.0))
    step = phi[1] - phi[0]
    assert abs(phi[np.argmax(kk["primary"])] - phi0) <= step
    assert kk["primary"].max() == pytest.approx(1.0, abs=1e-4)
    assert kk["primary"].min() < 0.01  # a real lobe, not a constant
    np.testing.assert_allclose(kk["diffuse"], np.sqrt(1.0 - (t @ l) ** 2), atol=1e-4)  # float32


def test_kajiya_kay_shifted_lobes_move_by_their_shift():
    shading = HairShading(primary_shift=-6.0, secondary_shift=9.0)
    phi, kk, phi0, _, _ = _sweep(shading)
    step = phi[1] - phi[0]
    # theta_h = asin(T.H) grows with phi here, so a lobe at theta_h = s peaks at phi0 + s
    assert abs(phi[np.argmax(kk["primary"])] - (phi0 - np.radians(6.0))) <= 1.5 * step
    assert abs(phi[np.argmax(kk["secondary"])] - (phi0 + np.radians(9.0))) <= 1.5 * step
    # the TRT lobe is broader than the R lobe
    assert (kk["secondary"] > 0.5).sum() > (kk["primary"] > 0.5).sum()


def test_mesh_lambert_matches_cosine_law():
    quad = Mesh(vertices=[(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)],
                faces=[(0, 1, 2), (0, 2, 3)], colours=(0.5, 0.5, 0.5), specular=0.0)
    albedo = srgb_to_linear(0.5)
    for degrees in (0.0, 60.0):
        a = np.radians(degrees)
        lighting = Lighting(key=Light(to_light=(np.sin(a), 0.0, np.cos(a)), colour=(1, 1, 1),
                                      intensity=1.0), ambient_intensity=0.0)
        rgb = render.render_buffers(FRONT, meshes=[quad], lighting=lighting,
                                    settings=flat_settings())["rgb"]
        np.testing.assert_allclose(rgb[H // 2, W // 2], albedo * np.cos(a), rtol=1e-3)


# -- shadows -----------------------------------------------------------------------------

def _two_sheets():
    """Two sheets of vertical strands, one in front of the other along +z (the light)."""
    x = np.linspace(-0.05, 0.05, 60)
    sheet = lambda z: [line((xi, -0.1, z), (xi, 0.1, z), 9) for xi in x]
    return Hair(points=sheet(0.02) + sheet(-0.02), colours=(0.6, 0.5, 0.4), widths=1e-3), len(x)


LIGHT_Z = Lighting(key=Light(to_light=(0.0, 0.0, 1.0), colour=(1, 1, 1), intensity=1.0),
                   ambient_intensity=0.05)


def test_hair_behind_hair_is_in_shadow():
    hair, n = _two_sheets()
    t = render.hair_shadow(hair, lighting=LIGHT_Z).reshape(2, n, 9)
    assert t[0].mean() > 0.9          # the sheet facing the light is lit
    assert t[1].mean() < 0.6          # the sheet behind it is not
    off = render.hair_shadow(hair, lighting=LIGHT_Z, shadows=ShadowSettings(enabled=False))
    np.testing.assert_array_equal(off, 1.0)


def test_shadowed_strands_render_darker():
    hair, _ = _two_sheets()
    side = Camera(eye=(1.0, 0.0, 0.0), target=(0.0, 0.0, 0.0), fov_y=20.0, width=W, height=H)
    z_px = side.project([(0.0, 0.0, 0.02), (0.0, 0.0, -0.02)])[:, 0].astype(int)
    rows = slice(H // 2 - 8, H // 2 + 8)
    lum = {}
    for on in (True, False):
        rgb = render.render_buffers(side, hair=hair, lighting=LIGHT_Z,
                                    settings=flat_settings(shadows=on), background=(0, 0, 0))["rgb"]
        lum[on] = [rgb[rows, z - 1:z + 2].sum(axis=-1).mean() for z in z_px]
    assert lum[False][1] > 0.1                      # the back sheet is visible and lit without
    assert lum[True][1] < 0.7 * lum[False][1]       # darker with shadows
    assert lum[True][0] == pytest.approx(lum[False][0], rel=0.1)  # front sheet unchanged


def test_hair_shadows_the_mesh():
    quad = Mesh(vertices=[(-0.3, -0.3, 0), (0.3, -0.3, 0), (0.3, 0.3, 0), (-0.3, 0.3, 0)],
                faces=[(0, 1, 2), (0, 2, 3)], colours=(0.7, 0.7, 0.7), specular=0.0)
    # light from 45 degrees to +x: a dense sheet at x = 0.1, z = 0.05 shades x ~ 0.05 on the quad
    x = np.linspace(0.08, 0.12, 40)
    hair = Hair(points=[line((xi, -0.2, 0.05), (xi, 0.2, 0.05), 9) for xi in x], widths=1e-3)
    lighting = Lighting(key=Light(to_light=(1.0, 0.0, 1.0), colour=(1, 1, 1), intensity=1.0),
                        ambient_intensity=0.0)
    sx = FRONT.project([(0.05, 0.0, 0.0), (-0.1, 0.0, 0.0)])[:, 0].astype(int)
    lum = {}
    for on in (True, False):
        rgb = render.render_buffers(FRONT, hair=hair, meshes=[quad], lighting=lighting,
                                    settings=flat_settings(shadows=on))["rgb"]
        lum[on] = [rgb[H // 2, s].sum() for s in sx]
    assert lum[False][0] == pytest.approx(lum[False][1], rel=0.02)  # same Lambert term
    assert lum[True][0] < 0.5 * lum[False][0]                        # under the hair
    assert lum[True][1] == pytest.approx(lum[False][1], rel=0.02)    # away from it


# -- meshes and depth --------------------------------------------------------------------

def _quad(z, half, colour):
    v = [(-half, -half, z), (half, -half, z), (half, half, z), (-half, half, z)]
    return Mesh(vertices=v, faces=[(0, 1, 2), (0, 2, 3)], colours=colour, specular=0.0)


@pytest.mark.parametrize("order", [0, 1])
def test_near_triangle_occludes_far(order):
    meshes = [_quad(0.1, 0.05, RED), _quad(0.0, 0.2, BLUE)]
    rgb = render.render_buffers(FRONT, meshes=meshes[::1 if order else -1], lighting=FLAT,
                                settings=flat_settings())["rgb"]
    np.testing.assert_allclose(rgb[H // 2, W // 2], RED, atol=1e-3)
    np.testing.assert_allclose(rgb[H // 2, W // 2 + 12], BLUE, atol=1e-3)


@pytest.mark.parametrize("z, visible", [(0.05, True), (-0.05, False)])
def test_hair_in_front_of_mesh_drawn_behind_hidden(z, visible):
    hair = Hair(points=[line((-0.2, 0.0, z), (0.2, 0.0, z))], colours=RED,
                widths=px_width(FRONT, 1.0, 3.0))
    out = render.render_buffers(FRONT, hair=hair, meshes=[_quad(0.0, 0.3, BLUE)], lighting=FLAT,
                                settings=flat_settings())
    row = out["rgb"][H // 2 - 1:H // 2 + 1, 20:W - 20].reshape(-1, 3)
    if visible:
        assert out["alpha"][H // 2 - 1:H // 2 + 1, 20:W - 20].min() > 0.99
        np.testing.assert_allclose(row, np.tile(RED, (len(row), 1)), atol=0.01)
    else:
        assert out["alpha"].max() == 0.0
        np.testing.assert_allclose(row, np.tile(BLUE, (len(row), 1)), atol=1e-3)


# -- output -----------------------------------------------------------------------------

def test_frame_is_uint8_srgb_of_camera_size():
    cam = Camera(eye=(0, 0, 1), target=(0, 0, 0), width=37, height=21)
    img = render.render_frame(cam, meshes=[_quad(0.0, 1.0, (0.5, 0.5, 0.5))], lighting=FLAT,
                              settings=flat_settings(supersample=2), background=(0, 0, 0))
    assert img.shape == (21, 37, 3) and img.dtype == np.uint8
    assert np.all(np.abs(img.astype(int) - 128) <= 1)  # sRGB 0.5 round-trips through linear


def test_default_settings_render_meshes_alone_and_hair_alone():
    quad = _quad(0.0, 0.3, (0.5, 0.5, 0.5))
    assert render.render_frame(FRONT, meshes=[quad]).mean() > 20
    hair = Hair(points=[line((-0.2, 0.0, 0.0), (0.2, 0.0, 0.0))], widths=px_width(FRONT, 1.0, 3.0))
    out = render.render_buffers(FRONT, hair=hair, lights=[render.DirectionalLight((0, 0, -1), (3, 3, 3))])
    assert out["alpha"].max() > 0.99 and np.isfinite(out["rgb"]).all()


def test_write_mp4_keeps_odd_size(tmp_path):
    frames = [np.full((25, 33, 3), 40 * k, np.uint8) for k in range(4)]
    path = render.write_mp4(tmp_path / "odd.mp4", frames, fps=10)
    import imageio.v2 as imageio
    got = [f for f in imageio.get_reader(path)]  # list() asks len(): inf for video
    assert len(got) == 4 and got[0].shape == (25, 33, 3)
    assert [round(float(g.mean()) / 40) for g in got] == [0, 1, 2, 3]


def test_turntable_writes_mp4_and_resumes(tmp_path):
    import imageio.v2 as imageio
    calls = []
    strands = np.stack([line((-0.2, y, 0.0), (0.2, y, 0.0)) for y in (-0.05, 0.0, 0.05)])

    def scene(frame):
        calls.append(frame)
        return strands, (0.5, 0.3, 0.1), 2e-3, [_quad(-0.1, 0.3, (0.6, 0.6, 0.6))]

    cam = Camera(eye=(0, 0, 1), target=(0, 0, 0), width=48, height=32)
    shot = Turntable(frames=6, degrees=90.0, fps=12)
    first = render.turntable(tmp_path, scene, cam, shot=shot, progress=False)
    assert calls == list(range(6)) and first["rendered"] == list(range(6))
    frames = [f for f in imageio.get_reader(first["video"])]
    assert len(frames) == 6 and frames[0].shape == (32, 48, 3)
    assert np.abs(frames[0].astype(int) - frames[3].astype(int)).mean() > 1.0  # it turns

    kept = imageio.imread(first["frames"][2])
    first["frames"][2].unlink()
    first["frames"][4].unlink()
    first["frames"][5].write_bytes(b"not a png")   # a frame cut short by a kill
    calls.clear()
    second = render.turntable(tmp_path, scene, cam, shot=shot, progress=False)
    assert calls == [2, 4, 5] and second["rendered"] == [2, 4, 5]
    assert imageio.get_reader(second["video"]).count_frames() == 6
    assert np.abs(imageio.imread(second["frames"][2]).astype(int) - kept).max() <= 2


# -- boundaries --------------------------------------------------------------------------

@pytest.mark.parametrize("make, name", [
    (lambda: Camera(fov_y=190.0), "fov_y"),
    (lambda: Camera(width=0), "width"),
    (lambda: Hair(points=np.zeros((2, 1, 3))), "points"),
    (lambda: Hair(points=np.zeros((2, 3, 3)), widths=-1.0), "widths"),
    (lambda: Hair(points=np.zeros((2, 3, 3)), colours=(2.0, 0.0, 0.0)), "colours"),
    (lambda: Mesh(vertices=np.zeros((3, 3)), faces=[(0, 1, 3)]), "faces"),
    (lambda: RenderSettings(layers=0), "layers"),
    (lambda: RenderSettings(compositor="abuffer"), "compositor"),
    (lambda: RenderSettings(strand_lod=0.0), "strand_lod"),
    (lambda: RenderSettings(shading_stride=3), "shading_stride"),
    (lambda: ShadowSettings(resolution=8), "resolution"),
    (lambda: Turntable(frames=0), "frames"),
])
def test_invalid_input_names_the_parameter(make, name):
    with pytest.raises(ValueError, match=name):
        make()


def test_render_keeps_the_existing_taichi_runtime():
    fp = ti.lang.impl.current_cfg().default_fp
    render.init("cpu")  # already initialised by conftest: must be a no-op
    assert ti.lang.impl.current_cfg().default_fp == fp


def test_render_knows_nothing_of_physics():
    import ast
    import pathlib
    for path in pathlib.Path(render.__file__).parent.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            assert not any(n.split(".")[0] == "taichi_hair" for n in names), path


def test_contact_sheet_takes_first_middle_last(tmp_path):
    from render.contact import contact_sheet
    for name, n in (("a", 5), ("b", 2)):
        frames = tmp_path / name / "frames"
        frames.mkdir(parents=True)
        for k in range(n):
            render.write_png(frames / f"frame_{k:05d}.png", np.full((40, 60, 3), 50 * k, np.uint8))
    (tmp_path / "empty").mkdir()
    r = contact_sheet([tmp_path / "a", tmp_path / "empty", tmp_path / "b"], tmp_path / "sheet.png",
                      thumb=30)
    assert r["rows"] == ["a", "b"] and r["skipped"] == [str(tmp_path / "empty")]
    sheet = render.read_png(r["path"])
    assert sheet.shape[0] == 2 * (22 + 20)
    # row a: frames 0, 2, 4 -> greys 0, 100, 200 below the label
    assert [int(sheet[30, 2 + 34 * j, 0]) for j in range(3)] == [0, 100, 200]


@pytest.mark.parametrize("direction", [(0.0, 1.0, 0.25), (0.7, -0.7, 0.2), (0.0, -1.0, 0.0)])
def test_fit_camera_centres_and_fills(direction):
    pts = np.random.default_rng(1).normal(size=(200, 3)) * [0.1, 0.05, 0.2] + [0.3, -0.2, 0.1]
    cam = render.fit_camera(pts, direction=direction, width=160, height=90, margin=1.05)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    box = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    s = cam.project(box)[:, :2]
    assert s.min() >= 0.0 and s[:, 0].max() <= 160 and s[:, 1].max() <= 90    # all in frame
    span = s.max(axis=0) - s.min(axis=0)
    assert max(span[0] / 160, span[1] / 90) > 0.8                             # and filling it
    np.testing.assert_allclose(cam.project(0.5 * (lo + hi))[:2], [80, 45], atol=4)  # centred


def test_capsule_mesh_and_three_point_lights():
    m = render.capsule_mesh((0, 0, 0), (0, 0, -0.2), 0.05)
    r = np.linalg.norm(m.vertices[:, :2], axis=1)
    assert np.all(r <= 0.05 + 1e-9) and m.vertices[:, 2].min() == pytest.approx(-0.25)
    assert m.vertices[:, 2].max() == pytest.approx(0.05)
    lights = render.three_point_lights((0.0, 1.0, 0.2))
    directional = [lt for lt in lights if isinstance(lt, render.DirectionalLight)]
    assert len(directional) == 3 and any(isinstance(lt, render.AmbientLight) for lt in lights)
    # the key lights the subject from the camera's side, the rim from behind
    assert np.dot(directional[0].to_light, (0.0, 1.0, 0.2)) > 0.3
    assert np.dot(directional[2].to_light, (0.0, 1.0, 0.2)) < -0.3


def test_a_frame_renders_to_the_same_bytes_every_time():
    """Dense crossing hair, shadows on, every thread Taichi has: the deep opacity map sums in
    fixed point and the tile sort breaks depth ties by segment, so no result depends on the
    order threads ran in (float atomics and scatter order made pixels differ between runs)."""
    rng = np.random.default_rng(3)
    starts = rng.uniform(-0.15, 0.15, (3000, 3))
    ends = starts + rng.normal(scale=0.08, size=(3000, 3))
    hair = Hair(points=[line(a, b, 6) for a, b in zip(starts, ends)], widths=2e-4)
    camera = Camera(eye=(0.0, -0.3, 0.8), target=(0.0, 0.0, 0.0), fov_y=40.0, width=160, height=120)
    lights = [render.DirectionalLight(direction=(-0.3, -0.5, -1.0), irradiance_rgb=(3.0, 3.0, 3.0))]
    frames = [render.render_frame(camera, hair=hair, lights=lights) for _ in range(4)]
    assert all(np.array_equal(frames[0], f) for f in frames[1:])
    assert frames[0].std() > 1.0  # hair was drawn


def test_culling_hidden_hair_changes_no_pixel(monkeypatch):
    """The tiled compositor bins hair before shading, drops segments from tiles where the
    meshes hide them, and shades only the vertices of segments binned somewhere: the frame
    is the same to the byte as binning and shading everything."""
    from render import tiles
    from render.bench import sphere_mesh, synthetic_hair
    hair = synthetic_hair(1000, 12, width=3e-4, seed=5)
    camera = Camera(eye=(0.05, 0.02, 0.62), target=(0.0, -0.06, 0.0), fov_y=40.0, width=320,
                    height=240)
    lights = render.three_point_lights((0.05, 0.02, 0.62), (0.0, 1.0, 0.0))
    frames, shaded = {}, {}
    for cull in (True, False):
        monkeypatch.setattr(tiles, "CULL_HIDDEN", cull)
        frames[cull] = render.render_buffers(camera, hair=hair, meshes=[sphere_mesh()],
                                             lights=lights)
        mark = render.runtime.buffer("hair_mark", ti.i32, (len(hair.vertices),))
        shaded[cull] = (mark.to_numpy() > 0).mean()
    assert frames[True]["alpha"].max() > 0.5   # hair in view
    assert shaded[True] < 0.9                  # and some hidden behind the head
    for k in ("image", "rgb", "alpha"):
        np.testing.assert_array_equal(frames[True][k], frames[False][k])


def test_device_copies_follow_the_groom():
    """Rendering the same Hair again reuses its device copies (its arrays are read-only);
    another groom of the same shape in between is uploaded, not mistaken for it."""
    from render.bench import synthetic_hair
    a, b = synthetic_hair(200, 8, seed=1), synthetic_hair(200, 8, seed=2)
    assert a.vertices.shape == b.vertices.shape
    camera = Camera(eye=(0.05, 0.02, 0.62), target=(0.0, -0.06, 0.0), fov_y=40.0, width=W,
                    height=H)
    first = render.render_frame(camera, hair=a)
    other = render.render_frame(camera, hair=b)
    again = render.render_frame(camera, hair=a)
    fresh = render.render_frame(camera, hair=Hair(points=a.points, colours=a.colours,
                                                  widths=a.widths))
    assert not np.array_equal(first, other)
    np.testing.assert_array_equal(first, again)
    np.testing.assert_array_equal(first, fresh)
    with pytest.raises(ValueError):
        a.vertices[0, 0] = 1.0


def test_frame_does_not_depend_on_how_work_is_chunked(monkeypatch):
    """Reductions and vertex shading walk contiguous runs per thread (few long runs on the
    CPU, many short ones elsewhere; shading reuses a fibre's constants along a run): the GPU
    chunking, run here on the CPU, gives the same bytes."""
    from render.bench import sphere_mesh, synthetic_hair
    hair = synthetic_hair(500, 12, width=2e-4, seed=7)
    camera = Camera(eye=(0.05, 0.02, 0.62), target=(0.0, -0.06, 0.0), fov_y=40.0, width=160,
                    height=120)
    lights = render.three_point_lights((0.05, 0.02, 0.62), (0.0, 1.0, 0.0))
    frames = []
    for cpu in (True, False):
        monkeypatch.setattr(render.runtime, "on_cpu", lambda cpu=cpu: cpu)
        frames.append(render.render_buffers(camera, hair=hair, meshes=[sphere_mesh()],
                                            lights=lights))
    assert frames[0]["alpha"].max() > 0.5
    for k in ("image", "rgb", "alpha"):
        np.testing.assert_array_equal(frames[0][k], frames[1][k])


def test_asked_hair_colour_renders_as_that_colour():
    """Six colours, platinum to black: the reference swatch (`render.swatch`, a seed other
    than the stored response's) renders each within Delta E2000 3 of the colour asked. With
    Chiang's inversion, used before, the swatch's plain mean was 12-23 away (brown as beige,
    black as grey)."""
    from render.swatch import colour_table
    rows = colour_table(seed=2)
    assert len(rows) == 6
    for r in rows:
        assert r["delta_e"] < 3.0, r


def test_colour_response_inversion_is_monotone_and_bounded():
    """sigma_for_colour: darker asks get more absorption, white none, and black the most."""
    from render.colour import response_sigma_grid, sigma_for_colour
    grey = np.linspace(0.0, 1.0, 11)[:, None] * np.ones(3)
    s = sigma_for_colour(grey)
    assert np.all(np.diff(s, axis=0) <= 0.0)
    assert np.allclose(s[-1], 0.0)
    assert np.all(s[0] <= response_sigma_grid()[-1])


def test_delta_e2000_matches_sharma_pairs():
    """CIEDE2000 on pairs from Sharma, Wu & Dalal (2005), table 1."""
    from render.colour import delta_e2000
    pairs = [((50.0, 2.6772, -79.7751), (50.0, 0.0, -82.7485), 2.0425),
             ((50.0, -1.3802, -84.2814), (50.0, 0.0, -82.7485), 1.0000),
             ((50.0, 2.5, 0.0), (73.0, 25.0, -18.0), 27.1492),
             ((2.0776, 0.0795, -1.1350), (0.9033, -0.0636, -0.5514), 0.9082)]
    for a, b, want in pairs:
        assert abs(float(delta_e2000(a, b)) - want) < 1e-3


def test_mesh_edges_are_antialiased():
    """A sphere's silhouette at one sample per pixel against the same frame supersampled 4 x 4:
    edge pixels blend mesh and background as the supersampled frame does (before: each pixel
    all mesh or all background, 46 pixels off by > 0.05, up to 0.52)."""
    from render.bench import sphere_mesh
    cam = Camera(eye=(0.0, 0.0, 0.5), target=(0.0, 0.0, 0.0), fov_y=30.0, width=64, height=48)
    m = sphere_mesh(radius=0.08)
    one = render.render_buffers(cam, meshes=[m], background=(0.1, 0.1, 0.1))["rgb"]
    ref = render.render_buffers(cam, meshes=[m], background=(0.1, 0.1, 0.1),
                                settings=RenderSettings(supersample=4))["rgb"]
    d = np.abs(one - ref).max(axis=-1)
    assert d.max() < 0.2 and (d > 0.05).sum() < 15, (d.max(), (d > 0.05).sum())


def test_subject_fraction_measures_rows_off_the_backdrop():
    """contact.subject_fraction: a 30-row block on a 100-row backdrop is 0.30 of the height;
    noise within the tolerance is backdrop; a blank frame is 0."""
    from render.contact import subject_fraction
    img = np.full((100, 80, 3), 82, np.uint8)
    img[::7, ::5] += 3
    assert subject_fraction(img) == 0.0
    img[40:70, 10:20] = (150, 110, 60)
    assert abs(subject_fraction(img) - 0.30) < 1e-9


def test_subject_extent_measures_width_and_the_border(tmp_path):
    """contact.subject_extent: a 2-row, 60-column bar on a 100 x 80 backdrop spans 0.02 of the
    height and 0.75 of the width and keeps off the border; moved onto the last column it
    touches it; framing takes the smallest of max(height, width) over the frames."""
    from render.contact import framing, subject_extent
    img = np.full((100, 80, 3), 82, np.uint8)
    img[50:52, 10:70] = (150, 110, 60)
    h, w, inside = subject_extent(img)
    assert abs(h - 0.02) < 1e-9 and abs(w - 0.75) < 1e-9 and inside
    img[50:52, 70:80] = (150, 110, 60)
    assert not subject_extent(img)[2]
    assert subject_extent(np.full((10, 10, 3), 5, np.uint8)) == (0.0, 0.0, True)
    standing = np.full((100, 80, 3), 82, np.uint8)
    standing[20:80, 40:42] = (150, 110, 60)
    for k, frame in enumerate((img, standing)):
        render.write_png(tmp_path / f"frame_{k:05d}.png", frame)
    measure = framing(sorted(tmp_path.glob("frame_*.png")))
    assert abs(measure["height"] - 0.02) < 1e-9 and abs(measure["fills"] - 0.6) < 1e-9
    assert measure["cut"] == 1


def test_contact_sheet_measures_framing_on_the_masks_beside_the_frames(tmp_path):
    """Frames of a shaded wall (a vertical ramp, every row unlike the top-left pixel) with a
    20-row figure: with mask_NNNNN.png beside each frame (the runner's `mask_path`) the sheet
    reads the figure's 20 of 100 rows; without masks, the ramp's rows too (all but the top ones
    within the tolerance of the top-left pixel)."""
    from render.contact import contact_sheet, subject_fraction
    from taichi_hair.app.runner import Shot, mask_path
    frames = tmp_path / "run" / "frames"
    image = np.repeat(np.linspace(60, 120, 100).astype(np.uint8)[:, None, None], 3, axis=2)
    image = np.ascontiguousarray(np.broadcast_to(image, (100, 50, 3)))
    mask = np.zeros_like(image)
    image[30:50, 20:30], mask[30:50, 20:30] = (200, 150, 100), 255
    for k in range(3):
        render.write_png(frames / f"frame_{k:05d}.png", image)
    assert contact_sheet([tmp_path / "run"], tmp_path / "a.png")["fractions"][0] > 0.85
    for k in range(3):
        render.write_png(mask_path(frames / f"frame_{k:05d}.png"), mask)
    assert mask_path(frames / "frame_00002.png") == frames / "mask_00002.png"
    assert contact_sheet([tmp_path / "run"], tmp_path / "b.png")["fractions"] == [pytest.approx(0.2)]
    with pytest.raises(ValueError, match="mask"):
        subject_fraction(image, mask=mask[:50])
    with pytest.raises(ValueError, match="masks"):
        Shot(masks=1)


def test_tight_fit_keeps_every_point_in_frame_and_fills_more():
    """fit_camera(tight=True) on a sphere's points: every point projects inside the frame,
    the sphere spans more of the frame's height than with the box's corners fitted, and the
    tightest point touches the frame within the margin."""
    rng = np.random.default_rng(0)
    p = rng.normal(size=(4000, 3))
    p = 0.1 * p / np.linalg.norm(p, axis=1, keepdims=True)
    spans = []
    for tight in (False, True):
        cam = render.fit_camera(p, direction=(0.0, 1.0, 0.25), width=320, height=240,
                                margin=1.02, tight=tight)
        s = cam.project(p)
        assert s[:, 0].min() >= 0 and s[:, 0].max() <= 320 and s[:, 1].min() >= 0 and s[:, 1].max() <= 240
        spans.append((s[:, 1].max() - s[:, 1].min()) / 240)
    assert spans[1] > spans[0] * 1.1 and spans[1] > 0.9, spans


@ti.kernel
def _visit_mixed(n: ti.i32, seen: ti.types.ndarray(dtype=ti.i32, ndim=1),
                 when: ti.types.ndarray(dtype=ti.i32, ndim=1)) -> ti.i32:
    span, factor = render.threads.spread(n)
    for step in range(span * factor):
        item = render.threads.spread_item(step, span, factor, n)
        if item >= 0:
            ti.atomic_add(seen[item], 1)
            when[item] = step
    return span * factor


@pytest.mark.parametrize("n", [1, 7, 300, 1200, 4096, 5000])
def test_mixed_loop_order_visits_every_item_once_and_spreads_runs(n):
    """The spread loop order (`render.threads.spread_item`: tiles, image and map rows, runs of
    vertices) is a permutation: every item once. And it mixes:
    the first half of the iterations (one CPU thread's block on 2 threads) holds items from
    every quarter of the range (the screen), in about equal numbers."""
    seen, when = ti.ndarray(ti.i32, (n,)), ti.ndarray(ti.i32, (n,))
    seen.fill(0)
    steps = _visit_mixed(n, seen, when)
    np.testing.assert_array_equal(seen.to_numpy(), np.ones(n, np.int32))
    if n >= 300:
        early = np.nonzero(when.to_numpy() < steps // 2)[0]
        counts = np.histogram(early, bins=4, range=(0, n))[0]
        assert counts.min() > 0.6 * len(early) / 4, counts


@ti.kernel
def _visit_runs(n: ti.i32, n_runs: ti.i32, seen: ti.types.ndarray(dtype=ti.i32, ndim=1)):
    span, factor = render.threads.spread(n_runs)
    for step in range(span * factor):
        lo, hi = render.threads.spread_run(step, span, factor, n, n_runs)
        for i in range(lo, hi):
            ti.atomic_add(seen[i], 1)


@pytest.mark.parametrize("n, n_runs", [(1, 1), (5, 7), (1000, 64), (4097, 4096), (620001, 4096)])
def test_spread_runs_cover_every_item_once(n, n_runs):
    """`render.threads.spread_run` (points, reductions, fibre shading): the runs of a spread
    loop cover 0..n-1 once each, whether runs outnumber items or not."""
    seen = ti.ndarray(ti.i32, (n,))
    seen.fill(0)
    _visit_runs(n, n_runs, seen)
    np.testing.assert_array_equal(seen.to_numpy(), np.ones(n, np.int32))
