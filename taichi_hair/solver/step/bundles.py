"""The kernels' arguments as bundles (Taichi argpacks of ndarrays) and the launch's scalars."""

import taichi as ti

from ...rods.arrays import Ints1, Ints2, ModelArgs, Scalars3, StateArgs, Vec3s1, Vec3s2, Vec3s3, Vec4s1
from .plan import stage_flags, StepPlan


DriveArgs = ti.types.argpack(
    head=Vec3s2, loads=Vec3s1, gusts=Vec3s1, modes=Vec3s2, user_force=Vec3s2, tools=Vec4s1,
    tool_points=Vec3s2, pin_mode=Ints2, pin_start=Vec3s2, pin_end=Vec3s2, clip=Vec3s3)


ContactArgs = ti.types.argpack(kinds=Ints1, geometry=Vec3s2, params=Vec4s1, sdf=Scalars3, sdf_meta=Vec3s1)


# h: the step [s]; stride: how many launch steps it spans (1, or a strand's own with
# StageFlags.strides: advance_strands sets h and stride per strand); k0: the launch's first step
# index in launch steps (time (k0 + k) h / stride at launch step k)
StepScalars = ti.types.struct(
    h=float, k0=float, drag=float, max_speed=float, projection_tol=float, projection_iterations=ti.i32,
    twist_tol=float, twist_iterations=ti.i32, n_analytic=ti.i32, pin_f0=float, pin_df=float, stride=ti.i32)


# The launch's scalars by name (StepScalars' members) as an argpack, which a kernel takes whole
# and gathers into StepScalars inside (gather_scalars), where it is free. One per StepBundles,
# rewritten before a launch only where a value changed (StepBundles.scalars): a member costs
# about 40 us to write, typically k0 alone per launch, while building an argpack or a struct
# in Python costs about 1 ms (Taichi 1.7.4, this 2-core machine under load) and passing 11
# loose scalars costs about what passing the argpack does.
ScalarArgs = ti.types.argpack(**{name: kind for name, kind in StepScalars.members.items() if name != "stride"})


@ti.func
def gather_scalars(sa: ti.template()):
    """The StepScalars of a launch's ScalarArgs."""
    return StepScalars(h=sa.h, k0=sa.k0, drag=sa.drag, max_speed=sa.max_speed, projection_tol=sa.projection_tol,
                       projection_iterations=sa.projection_iterations, twist_tol=sa.twist_tol,
                       twist_iterations=sa.twist_iterations, n_analytic=sa.n_analytic, pin_f0=sa.pin_f0,
                       pin_df=sa.pin_df, stride=1)


class StepBundles:
    """One simulator's kernel bundles, built once: model and state from the rods, contacts and
    drive from the control once `bind` gives it; the drive bundle is rebuilt only when user
    forces or pins first get their arrays."""

    def __init__(self, model, state):
        md, st = model, state
        self.model = ModelArgs(node_count=md.node_count, mass=md.mass, inv_mass=md.inv_mass,
                               rest_length=md.rest_length, voronoi=md.voronoi, stiffness=md.stiffness,
                               rest_kappa=md.rest_kappa, rest_twist=md.rest_twist, root_frame=md.root_frame)
        diag, upper, rhs = st.scratch_edge
        self.state = StateArgs(x=st.x, v=st.v, x_prev=st.x_prev, dx=st.dx, force=st.force, theta=st.theta,
                               bishop_u=st.bishop_u, bishop_v=st.bishop_v, m1=st.m1, m2=st.m2, kb=st.kb,
                               root_t=st.root_t, root_u=st.root_u, diag=diag, upper=upper, rhs=rhs,
                               counters=st.counters, residuals=st.residuals, history=st.history,
                               tension=st.tension, blocks=st.blocks, block_rhs=st.block_rhs)
        self._state, self._model, self._control, self.contacts = st, md, None, None
        self._drive_key, self._drive = None, None
        self._scalars, self._scalar_values = None, None
        self._kappa_model = (None, None)

    def bind(self, control) -> None:
        """Take the control arrays (control.Control) that drive the steps."""
        c = control
        self._control = c
        self.contacts = ContactArgs(kinds=c.kinds, geometry=c.geometry, params=c.params, sdf=c.sdf,
                                    sdf_meta=c.sdf_meta)
        self._drive_key = None

    def drive(self, pins=None):
        """The drive bundle; pins: None or the (mode, start, end, clip) arrays of the pin table
        (an unused flag's arrays are placeholders of the right type)."""
        st, c = self._state, self._control
        key = (id(c.user_force), None if pins is None else tuple(id(a) for a in pins))
        if key != self._drive_key:
            mode, start, end, clip = pins if pins is not None else (st.counters, st.dx, st.dx, st.history)
            self._drive = DriveArgs(head=c.head, loads=c.loads, gusts=c.gusts, modes=c.modes,
                                    user_force=c.user_force if c.user_force is not None else st.force,
                                    tools=c.tools, tool_points=c.tool_points, pin_mode=mode,
                                    pin_start=start, pin_end=end, clip=clip)
            self._drive_key = key
        return self._drive

    def scalars(self, plan: StepPlan, control, h: float, pin_fraction=(0.0, 0.0)):
        """The launch's ScalarArgs (step_scalars' values): this bundles' one argpack, its members
        rewritten where they changed since the last launch."""
        values = step_scalars(plan, control, h, pin_fraction)
        if self._scalars is None:
            self._scalars = ScalarArgs(**dict(zip(SCALAR_NAMES, values)))
        else:
            for name, value, last in zip(SCALAR_NAMES, values, self._scalar_values):
                if value != last:
                    self._scalars[name] = value
        self._scalar_values = values
        return self._scalars

    def model_with(self, rest_kappa=None):
        """The model bundle, or one with rest curvatures rest_kappa (a vec4 [S, N] ndarray) in
        place of the model's; the last one built is kept for the next call with the same array."""
        if rest_kappa is None:
            return self.model
        kappa, model = self._kappa_model
        if kappa is not rest_kappa:
            md = self._model
            model = ModelArgs(node_count=md.node_count, mass=md.mass, inv_mass=md.inv_mass,
                              rest_length=md.rest_length, voronoi=md.voronoi, stiffness=md.stiffness,
                              rest_kappa=rest_kappa, rest_twist=md.rest_twist, root_frame=md.root_frame)
            self._kappa_model = (rest_kappa, model)
        return model

    @property
    def rods(self):
        """(RodModel, RodState): the arrays the bundles hold."""
        return self._model, self._state

    def twist_drive(self, pins=None):
        """The drive bundle for the twist stage alone: `drive(pins)` once a control is bound,
        else placeholders of the right types (a RodSystem without a simulator has no clips)."""
        if self._control is not None:
            return self.drive(pins)
        st, md = self._state, self._model
        return DriveArgs(head=st.dx, loads=st.root_t, gusts=st.root_t, modes=st.dx, user_force=st.force,
                         tools=md.stiffness, tool_points=st.dx, pin_mode=st.counters, pin_start=st.dx,
                         pin_end=st.dx, clip=st.history)


# The launch's scalars in StepScalars' order (ScalarArgs' members; contact.py's slots)
SCALAR_NAMES = tuple(name for name in StepScalars.members if name != "stride")


def step_scalars(plan: StepPlan, control, h: float, pin_fraction=(0.0, 0.0)) -> tuple:
    """The launch's scalar values in SCALAR_NAMES' order: step h [s], the launch's first step index
    control.first_step (k0: time k0 h; a whole number, exact in float32 up to 2^24 steps); pins
    pin_fraction = (f0, df)."""
    values = dict(h=h, k0=float(control.first_step), drag=control.drag, max_speed=control.max_speed,
                  projection_tol=plan.projection_tol, projection_iterations=plan.projection_iterations,
                  twist_tol=plan.twist_tol, twist_iterations=plan.twist_iterations, n_analytic=plan.n_analytic,
                  pin_f0=pin_fraction[0], pin_df=pin_fraction[1])
    return tuple(values[name] for name in SCALAR_NAMES)


def launch_flags(plan: StepPlan, control, pins, moving_head: bool = False, strides: bool = False):
    """(flags, pin arrays or None, (f0, df)) of a launch; pins: None, or (pin_mode, pin_start,
    pin_end, clip, f0, df, clips) as `advance` takes them; strides: strands step at their own
    strides (counters' step_stride), where no pin, clip or touch tool needs every launch step."""
    arrays_, fraction, clips = (None, (0.0, 0.0), False) if pins is None else (pins[:4], pins[4:6], pins[6])
    flags = stage_flags(plan, user=control.user_force is not None, moving_head=moving_head,
                        pins=pins is not None, clips=clips, strides=strides and pins is None and not plan.touch)
    return flags, arrays_, fraction
