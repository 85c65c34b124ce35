"""The options model (taichi_hair/world/options.py): typed, frozen options checked once, the
flat keywords as a shim that builds the same objects, every cross-option refusal in one place,
and the modes as str enums."""

import dataclasses

import numpy as np
import pytest

import taichi_hair as th
from taichi_hair.app.settings import apply_settings
from taichi_hair.rods.modes import Integrator, Root, Strain, Twist
from taichi_hair.world.options import Environment, SolverOptions, split_keywords


def small_groom(n_strands=2, curly=False):
    roots = np.array([[0.01 * k, 0.0, 0.0] for k in range(n_strands)])
    if curly:
        return th.Groom.curly(roots, length=0.05, n_nodes=11, curl_radius=0.004, curl_pitch=0.006)
    return th.Groom.straight(roots, length=0.05, n_nodes=7)


def test_modes_are_strings_that_compare_hash_and_print_as_their_value():
    assert Twist.KMOCH == "kmoch" and hash(Twist.KMOCH) == hash("kmoch")
    assert {"kmoch": 1}[Twist.KMOCH] == 1
    assert f"{Root.FREE}" == "free" and str(Integrator.IMPLICIT) == "implicit"
    assert SolverOptions(twist="kmoch").twist is Twist.KMOCH
    with pytest.raises(ValueError, match=r"twist must be one of \('none', 'kmoch', 'quasistatic'\), got 'fancy'"):
        SolverOptions(twist="fancy")


@pytest.mark.parametrize("changes, message", [
    (dict(integrator="implicit", projection="shake"), "projection='shake' is the explicit step's"),
    (dict(integrator="implicit", extensible=True), "extensible=True runs with integrator='explicit'"),
    (dict(integrator="implicit", strand_contact=th.StrandContact()), "strand_contact runs with"),
    (dict(integrator="implicit", root="free"), "needs a held root"),
    (dict(projection_iterations=0), "projection_iterations must be an integer >= 1"),
    (dict(twist_tol=-1.0), "twist_tol must be a finite number > 0"),
    (dict(stability_factor=2.5), r"stability_factor must be a finite number > 0 and < 2"),
    (dict(max_speed=float("nan")), "max_speed must be a finite number > 0"),
    (dict(extensible="yes"), "extensible must be True or False"),
    (dict(strain="bent"), "strain must be one of"),
])
def test_solver_options_refuse_bad_values_and_pairs_in_one_place(changes, message):
    with pytest.raises(ValueError, match=message):
        SolverOptions(**changes)


def test_environment_checks_its_fields():
    with pytest.raises(ValueError, match="wind acts through air drag"):
        Environment(wind=(1.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="gravity must be a finite 3-vector"):
        Environment(gravity=(0.0, np.inf, 0.0))
    with pytest.raises(ValueError, match=r"touch\[0\] must be a Hand or a Grab"):
        Environment(touch=(1,))
    assert Environment().wind is None and not Environment().has_wind and not Environment(wind=(0, 0, 0)).has_wind


def test_refusals_that_depend_on_the_groom():
    curls = small_groom(curly=True)
    elliptic = th.Material(ellipticity=2.0)
    with pytest.raises(ValueError, match="twist='kmoch' on elliptic strands"):
        SolverOptions(integrator="implicit", twist="kmoch").for_groom(curls, elliptic)
    with pytest.raises(ValueError, match="twist='none' on elliptic strands"):
        SolverOptions(integrator="implicit", twist="none").for_groom(curls, elliptic)
    with pytest.raises(ValueError, match="Kmoch's rule was built on the DER measure"):
        SolverOptions(twist="kmoch", strain="rotation").for_groom(curls, elliptic)
    assert SolverOptions().for_groom(curls, elliptic).strain is Strain.ROTATION
    assert SolverOptions(twist="kmoch").for_groom(curls, elliptic).strain is Strain.DER


def test_flat_keywords_build_the_same_objects():
    solver, environment = split_keywords(None, None, {"twist": "none", "drag": 1e-3, "root_motion": None},
                                         "Simulator", aliases={"root_motion": "motion"})
    assert solver == SolverOptions(twist="none") and environment == Environment(drag=1e-3)
    with pytest.raises(TypeError, match="Simulator got an unexpected keyword 'dragg'"):
        split_keywords(None, None, {"dragg": 1.0}, "Simulator")


def test_simulator_from_typed_options_matches_the_flat_keywords():
    """Both spellings build one simulation: the same plan and, stepped, the same positions."""
    groom = small_groom()
    material = th.Material()
    flat = th.Simulator(groom, material, dt=1e-3, twist="none", drag=2e-4, wind=(0.1, 0.0, 0.0),
                        colliders=(th.Sphere(centre=(0.0, 0.0, -0.2), radius=0.05),))
    typed = th.Simulator(groom, material, dt=1e-3, solver=th.SolverOptions(twist="none"),
                         environment=th.Environment(drag=2e-4, wind=(0.1, 0.0, 0.0)),
                         head=th.Head(colliders=(th.Sphere(centre=(0.0, 0.0, -0.2), radius=0.05),)))
    assert flat.plan == typed.plan and flat.solver == typed.solver and flat.environment == typed.environment
    flat.step(5)
    typed.step(5)
    assert np.array_equal(flat.positions(), typed.positions())
    with pytest.raises(ValueError, match="give head= or colliders=, not both"):
        th.Simulator(groom, material, head=th.Head(), colliders=())


def test_scene_flat_names_read_and_set_the_options():
    groom = small_groom()
    scene = th.Scene(groom=groom, twist="kmoch", motion=th.Shake(), wind=(0.2, 0.0, 0.0))
    assert scene.solver.twist is Twist.KMOCH and scene.twist == "kmoch"
    assert scene.drag == 5e-4 and scene.environment.wind == (0.2, 0.0, 0.0)
    assert isinstance(scene.motion, th.Shake)
    changed = dataclasses.replace(scene, drag=1e-3)
    assert changed.environment.drag == 1e-3 and changed.solver == scene.solver
    swept, _ = apply_settings(scene, None, {"drag": 2e-4, "solver.root": "pinned"})
    assert swept.environment.drag == 2e-4 and swept.root is Root.PINNED
    with pytest.raises(AttributeError):
        scene.no_such_option
    with pytest.raises(TypeError, match="Scene got an unexpected keyword 'twst'"):
        th.Scene(groom=groom, twst="none")
