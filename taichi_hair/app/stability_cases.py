"""The stability matrix as data: StabilityCase (one scene's settings), BASE_CASE (human hair) and
the table of cases (STABILITY_CASES, FLOAT64_TWINS, REFUSALS), each a name, whether --quick runs
it, and the fields that differ from BASE_CASE. `report stability` runs them
(taichi_hair.app.stability_report)."""

from dataclasses import dataclass, replace


@dataclass(frozen=True, kw_only=True)
class StabilityCase:
    """One scene: n_strands strands of `length` [m] growing horizontally outward from roots on a
    circle of radius `spread` [m] (they swing down under gravity), or with head=True from roots
    on a sphere head (stability_report.HEAD_RADIUS, HEAD_MARGIN, centred on the shake's pivot) 30
    degrees from its crown, leaving the surface at 12 degrees toward the equator (curly: along its
    normal), so they fall onto it and drape over it.

    Material: E [Pa] (G = E / 3), radius [m], ellipticity (a/b >= 1); segment length [m]; curl
    radius [m] (0: straight; else pitch 2 curl_radius); dt [s]; twist mode.
    Head motion: a shake about +z, shake_deg at shake_hz [Hz] (0: still).
    Air: drag [N s/m per m]; wind [m/s] along +y with gusts of relative size `gust` and
    turbulence rms `turbulence` * wind (eddies 5 cm); wind needs drag > 0.
    Touch: grab_stiffness [N/m] > 0 adds a Grab (radius 3 cm) starting at the middle node of
    strand 0 and moving up at grab_speed [m/s]; hand_speed [m/s] > 0 sweeps a Hand (radius 3 cm)
    along +y through the hair of strand 0 (starting 10 cm before it).
    pin: "" none, "mid" (world pin on every strand's middle node), "clip" (clamp=True there),
    "tie" (head-attached pins there: they ride on the shake), "tip" (world pin on the tip).
    interaction: hair-hair interaction on a grid of `cell` [m] with `repulsion` [m^2/s^2] and
    `interaction_friction` [1/s].
    Limits: strict refuses dt past the bound; max_substeps caps automatic substeps.
    precision: the process the report runs the case in (run_stability_case runs it in this
    process's). quick: part of the --quick matrix. projection_iterations: the simulator's cap
    (lowered only to break a case on purpose)."""

    name: str
    youngs_modulus: float = 3e9
    radius: float = 40e-6
    ellipticity: float = 1.0
    segment: float = 0.01
    curl_radius: float = 0.0
    dt: float = 1e-3
    twist: str = "quasistatic"
    shake_hz: float = 0.0
    shake_deg: float = 30.0
    drag: float = 0.0
    wind: float = 0.0
    gust: float = 0.5
    turbulence: float = 0.1
    grab_stiffness: float = 0.0
    grab_speed: float = 0.0
    hand_speed: float = 0.0
    pin: str = ""
    interaction: bool = False
    cell: float = 0.02
    repulsion: float = 1.0
    interaction_friction: float = 5.0
    head: bool = False
    precision: str = "float32"
    strict: bool = False
    max_substeps: int = 1000
    length: float = 0.2
    n_strands: int = 4
    spread: float = 0.1
    projection_iterations: int = 100
    quick: bool = False
    integrator: str = "explicit"
    projection: str = "fast"


BASE_CASE = StabilityCase(name="human hair")
# the matrix's axes and the StabilityCase fields that make each (a case covers an axis when one
# of its fields differs from BASE_CASE)
STABILITY_AXES = {
    "E": ("youngs_modulus",), "radius": ("radius",), "ellipticity": ("ellipticity",), "segment": ("segment",),
    "curl": ("curl_radius",), "dt": ("dt",), "shake": ("shake_hz", "shake_deg"),
    "wind": ("wind", "gust", "turbulence"), "drag": ("drag",), "grab": ("grab_stiffness", "grab_speed"),
    "hand": ("hand_speed",), "pin": ("pin",),
    "interaction": ("interaction", "cell", "repulsion", "interaction_friction"),
    "head": ("head",), "twist": ("twist",), "precision": ("precision",), "limits": ("strict", "max_substeps"),
}  # the integrator and projection are not axes: `report stability --integrator implicit` (or
#   `--projection shake`) runs the whole matrix with it


def case_axes(case: StabilityCase) -> list:
    """The axes on which `case` differs from BASE_CASE (human hair, 1 cm segments, dt 1 ms)."""
    return [axis for axis, fields in STABILITY_AXES.items()
            if any(getattr(case, f) != getattr(BASE_CASE, f) for f in fields)]


# the extreme combinations: stiff or soft curly elliptic hair, 2 mm segments, dt 5 ms, shaken in a gale
EXTREME = dict(ellipticity=1.5, segment=0.002, curl_radius=0.005, dt=0.005, shake_hz=5.0, drag=0.0005, wind=30.0)

# (name, in --quick, fields that differ from BASE_CASE): every axis alone around human hair (E 3 GPa,
# r 40 um, round, straight, 1 cm segments, dt 1 ms, still, undamped, quasistatic twist, float32) from
# one end of its range to the other (a curl's polyline resolves it: segments of at most half the curl
# radius), then combinations
STABILITY_CASES = (
    ('human hair', True, dict()),
    ('human hair, twist none', True, dict(twist='none')),
    ('human hair, kmoch', True, dict(twist='kmoch')),
    ('E 1e+07 Pa', True, dict(youngs_modulus=1e+07)),
    ('E 1e+08 Pa', False, dict(youngs_modulus=1e+08)),
    ('E 1e+09 Pa', False, dict(youngs_modulus=1e+09)),
    ('E 1e+10 Pa', False, dict(youngs_modulus=1e+10)),
    ('E 1e+11 Pa', True, dict(youngs_modulus=1e+11)),
    ('radius 10 um', True, dict(radius=1e-05)),
    ('radius 20 um', False, dict(radius=2e-05)),
    ('radius 60 um', False, dict(radius=6e-05)),
    ('radius 100 um', False, dict(radius=0.0001)),
    ('radius 200 um', False, dict(radius=0.0002)),
    ('ellipticity 1.5', False, dict(ellipticity=1.5)),
    ('ellipticity 2', False, dict(ellipticity=2.0)),
    ('ellipticity 3', True, dict(ellipticity=3.0)),
    ('ellipticity 4', False, dict(ellipticity=4.0)),
    ('segment 1 mm', True, dict(segment=0.001)),
    ('segment 2 mm', False, dict(segment=0.002)),
    ('segment 5 mm', False, dict(segment=0.005)),
    ('segment 20 mm', False, dict(segment=0.02)),
    ('segment 30 mm', False, dict(segment=0.03)),
    ('curl 2 mm, 1 mm segments', True, dict(segment=0.001, curl_radius=0.002)),
    ('curl 5 mm, 2.5 mm segments', False, dict(segment=0.0025, curl_radius=0.005)),
    ('curl 10 mm, 5 mm segments', False, dict(segment=0.005, curl_radius=0.01)),
    ('curl 20 mm, 10 mm segments', False, dict(curl_radius=0.02)),
    ('dt 0.05 ms', True, dict(dt=5e-05)),
    ('dt 0.1 ms', False, dict(dt=0.0001)),
    ('dt 0.5 ms', False, dict(dt=0.0005)),
    ('dt 2 ms', False, dict(dt=0.002)),
    ('dt 5 ms', False, dict(dt=0.005)),
    ('dt 10 ms', False, dict(dt=0.01)),
    ('dt 20 ms', True, dict(dt=0.02)),
    ('shake 1 Hz 30 deg', False, dict(shake_hz=1.0)),
    ('shake 3 Hz 30 deg', False, dict(shake_hz=3.0)),
    ('shake 5 Hz 30 deg', True, dict(shake_hz=5.0)),
    ('shake 10 Hz 30 deg', False, dict(shake_hz=10.0)),
    ('shake 3 Hz 10 deg', False, dict(shake_hz=3.0, shake_deg=10.0)),
    ('shake 3 Hz 60 deg', False, dict(shake_hz=3.0, shake_deg=60.0)),
    ('shake 3 Hz 90 deg', True, dict(shake_hz=3.0, shake_deg=90.0)),
    ('drag 5e-4', False, dict(drag=0.0005)),
    ('drag 1e-2', True, dict(drag=0.01)),
    ('wind 5 m/s', False, dict(drag=0.0005, wind=5.0)),
    ('wind 15 m/s', False, dict(drag=0.0005, wind=15.0)),
    ('wind 30 m/s', False, dict(drag=0.0005, wind=30.0)),
    ('wind 60 m/s', True, dict(drag=0.0005, wind=60.0)),
    ('wind 30 m/s steady', False, dict(drag=0.0005, wind=30.0, gust=0.0, turbulence=0.0)),
    ('wind 30 m/s, gusts 100 %', False, dict(drag=0.0005, wind=30.0, gust=1.0)),
    ('wind 30 m/s, turbulence 30 %', True, dict(drag=0.0005, wind=30.0, turbulence=0.3)),
    ('grab 0.01 N/m, 0.5 m/s', False, dict(grab_stiffness=0.01, grab_speed=0.5)),
    ('grab 0.1 N/m, 0.5 m/s', False, dict(grab_stiffness=0.1, grab_speed=0.5)),
    ('grab 1 N/m, 0.5 m/s', False, dict(grab_stiffness=1.0, grab_speed=0.5)),
    ('grab 10 N/m, 0.5 m/s', False, dict(grab_stiffness=10.0, grab_speed=0.5)),
    ('grab 100 N/m, 0.5 m/s', True, dict(grab_stiffness=100.0, grab_speed=0.5)),
    ('grab 0.1 N/m, 0 m/s', False, dict(grab_stiffness=0.1)),
    ('grab 0.1 N/m, 2 m/s', False, dict(grab_stiffness=0.1, grab_speed=2.0)),
    ('grab 0.1 N/m, 10 m/s', True, dict(grab_stiffness=0.1, grab_speed=10.0)),
    ('hand 1 m/s', False, dict(hand_speed=1.0)),
    ('hand 5 m/s', True, dict(hand_speed=5.0)),
    ('pin mid', True, dict(pin='mid')),
    ('clip mid', False, dict(pin='clip')),
    ('tie mid, shake 3 Hz', True, dict(shake_hz=3.0, pin='tie')),
    ('pin tip, curl 1 cm', False, dict(segment=0.005, curl_radius=0.01, pin='tip')),
    ('interaction', True, dict(interaction=True, n_strands=8, spread=0.02)),
    ('interaction, repulsion 100', False, dict(interaction=True, repulsion=100.0, n_strands=8, spread=0.02)),
    ('interaction, friction 1000/s', False,
     dict(interaction=True, interaction_friction=1000.0, n_strands=8, spread=0.02)),
    ('interaction, 5 mm cells', False, dict(interaction=True, cell=0.005, n_strands=8, spread=0.02)),
    ('head', True, dict(head=True)),
    ('head, curl 5 mm', False, dict(segment=0.0025, curl_radius=0.005, head=True)),
    ('head, shake 5 Hz', True, dict(shake_hz=5.0, head=True)),
    ('head, gale 30 m/s', False, dict(drag=0.0005, wind=30.0, head=True)),
    ('curl 5 mm, ellipticity 1.5, none', False,
     dict(ellipticity=1.5, segment=0.0025, curl_radius=0.005, twist='none')),
    ('curl 5 mm, ellipticity 1.5, kmoch', False,
     dict(ellipticity=1.5, segment=0.0025, curl_radius=0.005, twist='kmoch')),
    ('curl 5 mm, ellipticity 1.5, quasistatic', False, dict(ellipticity=1.5, segment=0.0025, curl_radius=0.005)),
    ('curl 5 mm, ellipticity 4, none', False, dict(ellipticity=4.0, segment=0.0025, curl_radius=0.005, twist='none')),
    ('curl 5 mm, ellipticity 4, kmoch', True,
     dict(ellipticity=4.0, segment=0.0025, curl_radius=0.005, twist='kmoch')),
    ('curl 5 mm, ellipticity 4, quasistatic', False, dict(ellipticity=4.0, segment=0.0025, curl_radius=0.005)),
    ('extreme stiff, quasistatic', True, dict(youngs_modulus=1e+10, radius=0.0001, **EXTREME)),
    ('extreme soft, quasistatic', False, dict(youngs_modulus=1e+08, radius=2e-05, **EXTREME)),
    ('extreme stiff, kmoch', False, dict(youngs_modulus=1e+10, radius=0.0001, twist='kmoch', **EXTREME)),
    ('extreme soft, kmoch', False, dict(youngs_modulus=1e+08, radius=2e-05, twist='kmoch', **EXTREME)),
    ('E 1e11, r 200 um, 2 mm, dt 5 ms', False, dict(youngs_modulus=1e+11, radius=0.0002, segment=0.002, dt=0.005)),
    ('E 1e7, r 10 um, gale 60 m/s', False,
     dict(youngs_modulus=1e+07, radius=1e-05, drag=0.0005, wind=60.0, gust=1.0, turbulence=0.3)),
    ('coarse: E 1e7, 30 mm, dt 20 ms', False, dict(youngs_modulus=1e+07, segment=0.03, dt=0.02)),
    ('dt 20 ms, shake 10 Hz 90 deg', True, dict(dt=0.02, shake_hz=10.0, shake_deg=90.0)),
    ('curl 2 mm, e 4, kmoch, shake 10 Hz', True,
     dict(ellipticity=4.0, segment=0.001, curl_radius=0.002, twist='kmoch', shake_hz=10.0)),
    ('curl 2 mm, e 4, none, dt 10 ms', False,
     dict(ellipticity=4.0, segment=0.001, curl_radius=0.002, dt=0.01, twist='none')),
    ('grab 10 N/m, 2 m/s, pin mid', False, dict(grab_stiffness=10.0, grab_speed=2.0, pin='mid')),
    ('grab 100 N/m, 10 m/s, E 1e11', False, dict(youngs_modulus=1e+11, grab_stiffness=100.0, grab_speed=10.0)),
    ('hand 5 m/s, head, shake 3 Hz', False, dict(shake_hz=3.0, hand_speed=5.0, head=True)),
    ('head, tie, shake 10 Hz 60 deg', True, dict(shake_hz=10.0, shake_deg=60.0, pin='tie', head=True)),
    ('head, curl 5 mm, e 1.5, kmoch, interaction, shake 5 Hz, gale', True,
     dict(ellipticity=1.5, segment=0.0025, curl_radius=0.005, twist='kmoch', shake_hz=5.0, drag=0.0005, wind=30.0,
          interaction=True, head=True, n_strands=8)),
    ('interaction, repulsion 100, gale 60 m/s', False,
     dict(drag=0.0005, wind=60.0, interaction=True, repulsion=100.0, n_strands=8, spread=0.02)),
    ('segment 1 mm, E 1e10, dt 2 ms', False, dict(youngs_modulus=1e+10, segment=0.001, dt=0.002)),
    ('radius 200 um, ellipticity 4, segment 30 mm', False, dict(radius=0.0002, ellipticity=4.0, segment=0.03)),
    ('E 1e11, drag 1e-2, dt 10 ms', False, dict(youngs_modulus=1e+11, dt=0.01, drag=0.01)),
)
# float64 twins of these cases (named "<name>, float64"): the base, the ends of each range and the
# hardest combinations; (name, in --quick)
FLOAT64_TWINS = (
    ('human hair', True),
    ('human hair, kmoch', False),
    ('E 1e+07 Pa', False),
    ('E 1e+11 Pa', False),
    ('radius 10 um', False),
    ('radius 200 um', False),
    ('segment 1 mm', True),
    ('curl 2 mm, 1 mm segments', False),
    ('dt 20 ms', True),
    ('shake 3 Hz 90 deg', False),
    ('wind 60 m/s', False),
    ('grab 100 N/m, 0.5 m/s', False),
    ('hand 5 m/s', False),
    ('pin mid', True),
    ('tie mid, shake 3 Hz', False),
    ('interaction', True),
    ('head', True),
    ('curl 5 mm, ellipticity 4, kmoch', True),
    ('extreme stiff, quasistatic', False),
    ('extreme stiff, kmoch', True),
    ('E 1e7, r 10 um, gale 60 m/s', True),
    ('curl 2 mm, e 4, kmoch, shake 10 Hz', False),
    ('head, curl 5 mm, e 1.5, kmoch, interaction, shake 5 Hz, gale', False),
    ('segment 1 mm, E 1e10, dt 2 ms', False),
)
# refusals: a strict bound, and more automatic substeps than max_substeps
REFUSALS = (
    ('strict, dt 5 ms', True, dict(dt=0.005, strict=True)),
    ('strict, E 1e10, 2 mm', False, dict(youngs_modulus=1e+10, segment=0.002, strict=True)),
    ('strict, grab 100 N/m', False, dict(grab_stiffness=100.0, grab_speed=0.5, strict=True)),
    ('E 1e11, 1 mm, dt 20 ms (max_substeps)', True, dict(youngs_modulus=1e+11, segment=0.001, dt=0.02)),
    ('drag 1, dt 20 ms (max_substeps 100)', False, dict(dt=0.02, drag=1.0, max_substeps=100)),
)


def stability_cases(quick: bool) -> list:
    """The matrix in order: STABILITY_CASES, their FLOAT64_TWINS, then REFUSALS, as StabilityCase;
    quick: the cases marked quick (a third, covering every axis)."""
    matrix = [replace(BASE_CASE, name=name, quick=q, **changes) for name, q, changes in STABILITY_CASES]
    by_name = {case.name: case for case in matrix}
    twins = [replace(by_name[name], name=f"{name}, float64", precision="float64", quick=q) for name, q in FLOAT64_TWINS]
    refusals = [replace(BASE_CASE, name=name, quick=q, **changes) for name, q, changes in REFUSALS]
    cases = matrix + twins + refusals
    return [c for c in cases if c.quick] if quick else cases
