"""Cameras: a perspective look-at camera for frames and an orthographic view for the key light.

Both reduce to the same pair handed to kernels: `view`, a 4x4 float32 world -> eye matrix
(eye looks down -z, +y up), and `proj = (scale, cx, cy, ortho)`. A point projects to screen
`(sx, sy, depth, inv_w)`: pixels with (0, 0) the top-left corner of the top-left pixel, depth
in metres along the view axis, and `inv_w` the weight that makes screen-space interpolation
perspective-correct (1/depth for perspective, 1 for orthographic).
"""

from dataclasses import dataclass, replace

import numpy as np
import taichi as ti

vec3f = ti.types.vector(3, ti.f32)
vec4f = ti.types.vector(4, ti.f32)
mat4f = ti.types.matrix(4, 4, ti.f32)
f32 = ti.f32


def _vec3(name: str, value) -> np.ndarray:
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be 3 finite numbers, got {value!r}")
    return v


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """World -> eye matrix, shape (4, 4), float32; the eye sits at `eye` [m] looking at `target`."""
    fwd = target - eye
    fwd = fwd / np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    right = right / np.linalg.norm(right)
    true_up = np.cross(right, fwd)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = right, true_up, -fwd
    m[:3, 3] = -m[:3, :3] @ eye
    return m.astype(np.float32)


@dataclass(frozen=True, kw_only=True)
class Camera:
    """Perspective look-at camera.

    eye, target [m]: positions; up: approximate up direction (not parallel to target - eye).
    fov_y [degrees]: vertical field of view in (0, 180). width, height [pixels] >= 1.
    near [m] > 0: geometry nearer than this is dropped (segments and triangles are culled
    whole, not clipped).
    """

    eye: tuple = (0.0, 0.0, 1.0)
    target: tuple = (0.0, 0.0, 0.0)
    up: tuple = (0.0, 1.0, 0.0)
    fov_y: float = 40.0
    width: int = 640
    height: int = 480
    near: float = 1e-3

    def __post_init__(self):
        eye, target, up = (_vec3(n, getattr(self, n)) for n in ("eye", "target", "up"))
        for n, v in (("eye", eye), ("target", target), ("up", up)):
            object.__setattr__(self, n, tuple(float(c) for c in v))
        fwd = target - eye
        if np.linalg.norm(fwd) < 1e-9:
            raise ValueError(f"eye and target must differ, got eye={self.eye} target={self.target}")
        if np.linalg.norm(np.cross(fwd / np.linalg.norm(fwd), up)) < 1e-6:
            raise ValueError(f"up must not be parallel to target - eye, got up={self.up}")
        if not 0.0 < self.fov_y < 180.0:
            raise ValueError(f"fov_y must be in (0, 180) degrees, got {self.fov_y}")
        for n in ("width", "height"):
            v = getattr(self, n)
            if int(v) != v or v < 1:
                raise ValueError(f"{n} must be an integer >= 1 pixel, got {v}")
            object.__setattr__(self, n, int(v))
        if not self.near > 0.0:
            raise ValueError(f"near must be > 0 m, got {self.near}")

    @property
    def focal_px(self) -> float:
        """Focal length in pixels: a 1 m object at 1 m depth spans this many pixels."""
        return 0.5 * self.height / np.tan(np.radians(self.fov_y) / 2.0)

    def matrices(self, scale: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """(view (4, 4) float32, proj (4,) float32) for kernels, for an image `scale` times
        the camera's resolution (supersampling)."""
        view = look_at(np.array(self.eye), np.array(self.target), np.array(self.up))
        proj = np.array([self.focal_px * scale, 0.5 * self.width * scale,
                         0.5 * self.height * scale, 0.0], dtype=np.float32)
        return view, proj

    def project(self, points) -> np.ndarray:
        """Screen coordinates of world points [m], shape (..., 3) -> (..., 3): x, y [pixels],
        depth [m]. Pixel (i, j) has its centre at x = i + 0.5, y = j + 0.5 (y down)."""
        view, proj = self.matrices()
        p = np.asarray(points, dtype=np.float64)
        c = p @ view[:3, :3].T.astype(np.float64) + view[:3, 3]
        depth = -c[..., 2]
        k = proj[0] / depth
        return np.stack([proj[1] + k * c[..., 0], proj[2] - k * c[..., 1], depth], axis=-1)

    def metres_per_pixel(self, depth: float) -> float:
        """Width [m] of one pixel at `depth` [m]: widths in pixels times this are world widths."""
        return float(depth) / self.focal_px

    def orbit(self, degrees: float) -> "Camera":
        """This camera with its eye turned `degrees` about the up axis through the target
        (counter-clockwise seen from above)."""
        up = np.array(self.up) / np.linalg.norm(self.up)
        r = np.array(self.eye) - np.array(self.target)
        a = np.radians(degrees)
        # Rodrigues' rotation of the eye offset about `up`
        r = r * np.cos(a) + np.cross(up, r) * np.sin(a) + up * (up @ r) * (1.0 - np.cos(a))
        return replace(self, eye=tuple(np.array(self.target) + r))


@dataclass(frozen=True, eq=False)
class OrthoView:
    """Orthographic view along a direction, fitted to a bounding sphere; used for the key light.

    to_light: unit vector from the scene towards the light. centre [m], radius [m]: the sphere
    holding all geometry. resolution: the square map's side in texels.
    """

    to_light: np.ndarray
    centre: np.ndarray
    radius: float
    resolution: int

    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """(view (4, 4) float32, proj (4,) float32); depths run from ~0.05 r to ~2.05 r."""
        d = self.to_light / np.linalg.norm(self.to_light)
        helper = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
        eye = self.centre + d * self.radius * 1.05
        view = look_at(eye, self.centre, helper)
        n = self.resolution
        proj = np.array([n / (2.0 * self.radius), 0.5 * n, 0.5 * n, 1.0], dtype=np.float32)
        return view, proj

    @property
    def texel_size(self) -> float:
        """Side of one texel [m]."""
        return 2.0 * self.radius / self.resolution


@ti.func
def unit(v: vec3f) -> vec3f:
    """v / |v| in float32 (Vector.normalized promotes to the process's default float)."""
    return v * ti.rsqrt(ti.max(v.dot(v), f32(1e-24)))


@ti.func
def project(view: mat4f, proj: vec4f, p: vec3f) -> vec4f:
    """World point p [m] -> (sx, sy [pixels], depth [m], inv_w), see the module docstring."""
    c = view @ vec4f(p[0], p[1], p[2], f32(1.0))
    depth = -c[2]
    inv_w = f32(1.0)
    if proj[3] == 0.0:
        inv_w = f32(1.0) / ti.max(depth, f32(1e-12))
    k = proj[0] * inv_w
    return vec4f(proj[1] + k * c[0], proj[2] - k * c[1], depth, inv_w)


@ti.kernel
def project_vertices(n: ti.i32, x: ti.types.ndarray(dtype=vec3f, ndim=1),
                     width: ti.types.ndarray(dtype=f32, ndim=1),
                     view: mat4f, proj: vec4f,
                     screen: ti.types.ndarray(dtype=vec4f, ndim=1),
                     width_px: ti.types.ndarray(dtype=f32, ndim=1)):
    """screen[i] = project(x[i]); width_px[i] = width[i] [m] in pixels at x[i]'s depth.
    Shapes (V,), the first n used. One thread per vertex."""
    for i in range(n):
        s = project(view, proj, x[i])
        screen[i] = s
        width_px[i] = width[i] * proj[0] * s[3]


def fit_camera(points, *, direction=(0.0, 1.0, 0.25), up=(0.0, 0.0, 1.0), fov_y: float = 35.0,
               width: int = 640, height: int = 480, margin: float = 1.08,
               tight: bool = False) -> Camera:
    """A camera looking along -direction (direction: from the subject towards the eye) at the
    centre of the bounding box of `points` [m] (N, 3), just far enough that every corner of
    the box projects inside the frame with `margin` (> 1) to spare: the subject centred and
    filling the frame. tight: every point, rather than every corner of their box, projects
    inside (a rounded subject then fills more of the frame: the box's corners nearest the eye
    are empty space that perspective would make room for)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0 or not np.all(np.isfinite(p)):
        raise ValueError("points must be a non-empty finite (N, 3) array [m]")
    if not margin >= 1.0:
        raise ValueError(f"margin must be >= 1, got {margin}")
    d = _vec3("direction", direction)
    d = d / np.linalg.norm(d)
    lo, hi = p.min(axis=0), p.max(axis=0)
    centre = 0.5 * (lo + hi)
    corners = (p if tight else np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                                         for z in (lo[2], hi[2])])) - centre
    u = np.asarray(up, dtype=np.float64)
    right = np.cross(-d, u)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, -d)
    tan_y = np.tan(np.radians(fov_y) / 2.0)
    tan_x = tan_y * width / height
    # a corner at offsets (a right, b up, c towards the eye) fits when |a| <= tan_x (dist - c)
    a, b, c = corners @ right, corners @ true_up, corners @ d
    dist = margin * max(np.max(c + np.abs(a) / tan_x), np.max(c + np.abs(b) / tan_y), 1e-3)
    return Camera(eye=tuple(centre + d * dist), target=tuple(centre), up=tuple(u), fov_y=fov_y,
                  width=width, height=height, near=max(1e-3, 1e-3 * dist))
