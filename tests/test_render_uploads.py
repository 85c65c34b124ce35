"""A simulation's frames rebuild the Hair every frame with the same strands, colour and width:
the per-vertex arrays that depend only on those are shared with the last such Hair (so the
renderer finds the arrays it uploaded last and skips the upload), and they hold what the
per-strand path computes."""

import numpy as np

import render
from render import Camera, Hair
from render.runtime import upload

SHARED = ("vertex_colours", "vertex_widths", "vertex_sigma", "vertex_beta_m")


def strands(seed, n=40, m=9):
    rng = np.random.default_rng(seed)
    start = rng.uniform(-0.05, 0.05, size=(n, 1, 3))
    step = np.zeros((1, m, 3))
    step[0, :, 1] = -np.linspace(0.0, 0.1, m)
    return start + step + rng.normal(scale=1e-3, size=(n, m, 3))


def test_hair_of_one_colour_shares_its_vertex_arrays_with_the_last():
    colour, width = (0.28, 0.17, 0.09), 1.5e-4
    first = Hair(points=strands(0), colours=colour, widths=width)
    again = Hair(points=strands(1), colours=colour, widths=width)
    for name in SHARED:
        assert getattr(again, name) is getattr(first, name), name
        assert not getattr(again, name).flags.writeable
    # the values: as the per-strand path (not shared) computes them for the same colour
    per_strand = Hair(points=strands(1), colours=np.tile(colour, (40, 1)), widths=np.full(40, width))
    for name in SHARED:
        np.testing.assert_array_equal(getattr(again, name), getattr(per_strand, name))
    # another colour, width or strand length is computed afresh
    for other in (Hair(points=strands(1), colours=(0.3, 0.17, 0.09), widths=width),
                  Hair(points=strands(1), colours=colour, widths=2e-4),
                  Hair(points=strands(1, m=8), colours=colour, widths=width)):
        assert other.vertex_colours is not again.vertex_colours
    assert not np.array_equal(Hair(points=strands(1), colours=(0.3, 0.17, 0.09),
                                   widths=width).vertex_colours, again.vertex_colours)


def test_next_frame_hands_the_renderer_the_same_arrays_but_positions(monkeypatch):
    """`runtime.upload` skips a read-only array that is the very object it copied last: of the
    hair's per-vertex inputs, only the positions are new objects on the next frame."""
    cam = Camera(eye=(0.0, -0.05, 0.4), target=(0.0, -0.05, 0.0), fov_y=30.0, width=32, height=24)
    colour, width = (0.28, 0.17, 0.09), 1.5e-4
    seen = []

    def recording(name, array, dtype, n=0):
        seen.append((name, array))
        return upload(name, array, dtype, n)

    monkeypatch.setattr(render.frame, "upload", recording)
    frames = []
    for seed in (2, 3):
        seen.clear()
        render.render_buffers(cam, hair=Hair(points=strands(seed), colours=colour, widths=width))
        frames.append({name: array for name, array in seen if name.startswith("hair_")})
    new = sorted(name for name, array in frames[1].items()
                 if array is not frames[0][name] or array.flags.writeable)
    assert new == ["hair_irradiance", "hair_to_light", "hair_x"]


def test_frames_of_a_shared_hair_render_as_a_fresh_one():
    cam = Camera(eye=(0.0, -0.05, 0.4), target=(0.0, -0.05, 0.0), fov_y=30.0, width=64, height=48)
    colour, width = (0.28, 0.17, 0.09), 4e-4
    Hair(points=strands(4), colours=colour, widths=width)
    shared = Hair(points=strands(5), colours=colour, widths=width)
    fresh = Hair(points=strands(5), colours=np.tile(colour, (40, 1)), widths=width)
    assert shared.vertex_sigma is not fresh.vertex_sigma
    a, b = (render.render_buffers(cam, hair=h) for h in (shared, fresh))
    assert a["alpha"].max() > 0.1
    np.testing.assert_array_equal(a["image"], b["image"])
