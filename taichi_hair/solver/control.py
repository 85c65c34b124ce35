"""What drives the steps: head poses, loads, wind tables, colliders and touch tools, packed
into the small Taichi arrays the step kernels read. Built once per simulator; per launch only
the head poses and tool positions change."""

from dataclasses import dataclass, field

import numpy as np

from ..rods import arrays
from ..world.colliders import MeshCollider, pack_colliders, pack_grids
from ..world.forces import N_GUSTS, N_MODES, Wind, touch_table

MAX_STEPS_PER_LAUNCH = 256  # bounds the per-launch buffers of head poses and tool positions


@dataclass
class Control:
    """Kernel-side drive of a simulator.

    head: [K+1, 4] vec3 head poses (rows of R, then t [m]); loads: [2] vec3 (gravity [m/s^2],
    mean wind [m/s]); gusts [N_GUSTS] and modes [N_MODES, 3] vec3 wind tables; drag [N s/m per
    metre]; user_force [S, N] vec3 [N] or None; kinds/geometry/params: analytic colliders;
    sdf [NX, NY, NZ] m and sdf_meta [4 G] vec3: the G mesh colliders' distance grids
    (colliders.pack_grids);
    tools [T] vec4 and tool_points [K+1, T] vec3; max_speed [m/s]; first_step: the index of the
    launch's first (sub)step since t = 0 (the kernels take time as index x step, never as a sum
    carried from launch to launch, so the grouping of steps into launches changes nothing)."""

    head: object
    loads: object
    gusts: object
    modes: object
    drag: float
    user_force: object
    kinds: object
    geometry: object
    params: object
    sdf: object
    sdf_meta: object
    tools: object
    tool_points: object
    max_speed: float
    first_step: float = 0.0
    host: dict = field(default_factory=dict)  # numpy twins of head and tool_points (load_poses)


def build_control(gravity, wind, drag, colliders, touch, max_speed) -> tuple[Control, dict]:
    """Control arrays and the facts the step plan needs (n_analytic, mesh, wind_field, touch)."""
    wind_obj = wind if isinstance(wind, Wind) else None
    mean_wind = np.asarray(wind_obj.velocity if wind_obj else wind, dtype=np.float64)
    if wind_obj is not None:
        gusts, modes = wind_obj.tables()
    else:
        gusts, modes = np.zeros((N_GUSTS, 3)), np.zeros((N_MODES, 3, 3))
    meshes = [c for c in colliders if isinstance(c, MeshCollider)]
    n_analytic, kinds, geometry, params = pack_colliders(colliders)
    sdf, meta = pack_grids(meshes)
    tool_params, _ = touch_table(touch, [])
    identity = np.vstack([np.eye(3), np.zeros((1, 3))])
    control = Control(
        head=arrays.vectors(3, (MAX_STEPS_PER_LAUNCH + 1, 4), identity[None]),
        loads=arrays.vectors(3, (2,), np.stack([gravity, mean_wind])),
        gusts=arrays.vectors(3, (N_GUSTS,), gusts), modes=arrays.vectors(3, (N_MODES, 3), modes),
        drag=float(drag), user_force=None,
        kinds=arrays.ints(kinds.shape, kinds), geometry=arrays.vectors(3, geometry.shape[:2], geometry),
        params=arrays.vectors(4, params.shape[:1], params),
        sdf=arrays.scalars(sdf.shape, sdf), sdf_meta=arrays.vectors(3, (max(len(meta), 1),), meta if len(meta) else None),
        tools=arrays.vectors(4, tool_params.shape[:1], tool_params),
        tool_points=arrays.vectors(3, (MAX_STEPS_PER_LAUNCH + 1, tool_params.shape[0])),
        max_speed=float(max_speed))
    facts = {"n_analytic": n_analytic, "mesh": bool(meshes), "touch": bool(touch),
             "wind_field": wind_obj is not None and (wind_obj.gust_amplitude > 0 or wind_obj.turbulence > 0),
             "wind": bool(np.any(mean_wind)) or wind_obj is not None}
    return control, facts


def load_poses(control: Control, poses: np.ndarray) -> None:
    """Head poses [K+1, 4, 3] into the head buffer (rows past K+1 are left as they were). The
    host copy is kept between launches: reading the device buffer back cost as much as writing."""
    buffer = _host_copy(control, "head")
    buffer[: len(poses)] = poses
    control.head.from_numpy(buffer)


def load_tools(control: Control, touch, times) -> None:
    """Tool positions at `times` [K+1] into the tool buffer."""
    if not touch:
        return
    _, positions = touch_table(touch, times)
    buffer = _host_copy(control, "tool_points")
    buffer[: len(times)] = positions
    control.tool_points.from_numpy(buffer)


def _host_copy(control: Control, name: str) -> np.ndarray:
    """The numpy twin of control.<name> (made on first use from the device array), in the
    arrays' float type."""
    host = control.host.get(name)
    if host is None:
        host = control.host[name] = getattr(control, name).to_numpy().astype(arrays.np_float())
    return host
