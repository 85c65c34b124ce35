"""USD hair: `UsdGeom.BasisCurves` grooms in, animated linear curves out.

Needs the optional extra `usd` (`pip install 'taichi_hair[usd]'`, Pixar's usd-core). Nothing
here imports `pxr` at module import time: the first call that needs it does, and raises an
ImportError naming the extra when it is missing.

Reading (`read_usd_curves`): every BasisCurves prim (or one by path), points taken to world
space by the prim's local-to-world transform, a Y-up stage turned to our Z-up (x, y, z) ->
(x, -z, y) (a +90 degree turn about x), scaled by the stage's metersPerUnit. Cubic curves
(bezier, bspline, catmullRom; nonperiodic or pinned wrap) are evaluated to polylines of
`n_nodes` nodes evenly spaced in the curve parameter (segment k covers parameter [k, k+1]).

Writing (`UsdCurvesWriter`, `write_usd_curves`): linear, nonperiodic BasisCurves with
time-sampled points and extent, per-node widths, a per-curve `displayColor`; stage metadata
metersPerUnit 1, upAxis Z, timeCodesPerSecond = framesPerSecond = fps, start/end time codes;
optionally the head as a Mesh under an Xform with a time-sampled transform. Time code c is the
simulated time c / fps. The stage is kept in memory and after every frame exported whole to a
temporary file renamed over the target, so the file on disk is always complete and valid.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .hairfile import HairFileError, coordinate_problem
from .usd_pxr import EXTRA_HINT, require_pxr  # noqa: F401
# the package and its users take the writer from here
from .usd_write import UsdCurvesWriter, write_usd_curves  # noqa: F401

CUBIC_BASES = ("bezier", "bspline", "catmullRom")


@dataclass(eq=False)
class UsdCurves:
    """Strands read from a USD file, in metres, z up.

    groom: th.Groom of every strand (curves in prim order, then curve order).
    widths: list of [N_i] arrays (m; scaled by metersPerUnit and the prim transform's mean
        scale), one per strand, or None when no prim has widths.
    colors: [S, 3] float per-strand displayColor (uniform; a constant colour is repeated, a
        vertex or varying colour is taken at the root), NaN for prims without one; None when
        no prim has one.
    prims: [S] the prim path of each strand; curve_index: int64 [S], its curve in that prim.
    primvars: name -> [S, ...] every other per-curve (uniform or constant) primvar found on all
        curve prims read.
    """

    groom: object
    widths: list | None
    colors: np.ndarray | None
    prims: list
    curve_index: np.ndarray
    primvars: dict


# ---------------------------------------------------------------------------------------- read


def read_usd_curves(path, prim=None, n_nodes=None, time=None) -> UsdCurves:
    """Strands from every `UsdGeom.BasisCurves` prim of a USD file (or the one at `prim`).

    n_nodes: nodes per strand for cubic curves (>= 3), evenly spaced in the curve parameter;
        default 3 per segment plus one. Linear curves keep their points.
    time: time code to read (default: each attribute's default value, else its earliest sample).
    Raises HairFileError naming the file (and prim) for a missing or unreadable file, no curves,
    a curve with fewer than 3 points (or too few for its cubic basis), non-finite points,
    counts that do not add up, periodic curves, or an unknown basis."""
    Usd, UsdGeom, Sdf, Vt, Gf = require_pxr()
    path = Path(path)
    if n_nodes is not None and not (isinstance(n_nodes, (int, np.integer)) and n_nodes >= 3):
        raise ValueError(f"n_nodes must be an integer >= 3, got {n_nodes!r}")
    if not path.is_file():
        raise HairFileError(f"{path}: no such file")
    try:
        stage = Usd.Stage.Open(str(path))
    except Exception as exc:  # pxr.Tf.ErrorException and friends
        raise HairFileError(f"{path}: not a readable USD file ({' '.join(str(exc).split())[:300]})") from None
    if stage is None:
        raise HairFileError(f"{path}: not a readable USD file")
    code = Usd.TimeCode.EarliestTime() if time is None else Usd.TimeCode(float(time))
    scale = float(UsdGeom.GetStageMetersPerUnit(stage))
    if not (np.isfinite(scale) and scale > 0):
        raise HairFileError(f"{path}: metersPerUnit must be > 0, got {scale}")
    up = UsdGeom.GetStageUpAxis(stage)
    if up not in (UsdGeom.Tokens.y, UsdGeom.Tokens.z):
        raise HairFileError(f"{path}: upAxis must be Y or Z, got {str(up)!r}")
    y_up = up == UsdGeom.Tokens.y
    prims = _curve_prims(stage, path, prim, UsdGeom)
    strands, widths, colors, names, index, uniform = [], [], [], [], [], []
    for p in prims:
        s, w, c, pv = _read_prim(p, path, code, n_nodes, UsdGeom)
        world = np.asarray(UsdGeom.Xformable(p).ComputeLocalToWorldTransform(code), dtype=np.float64)
        if not np.all(np.isfinite(world)) or abs(np.linalg.det(world[:3, :3])) == 0:
            raise HairFileError(f"{path}: prim {p.GetPath()}: its transform is not finite or is singular")
        mean_scale = abs(np.linalg.det(world[:3, :3])) ** (1.0 / 3.0)
        # every curve of the prim in one product: a product per curve cost 1e6 calls on 1e6 curves
        x = np.concatenate(s) @ world[:3, :3] + world[3, :3]
        if y_up:
            x = np.stack([x[:, 0], -x[:, 2], x[:, 1]], axis=1)
        x *= scale
        problem = coordinate_problem(x, "point (in metres, transformed)")
        if problem:
            raise HairFileError(f"{path}: prim {p.GetPath()}: {problem}")
        strands.extend(np.split(x, np.cumsum([len(pts) for pts in s])[:-1]))
        widths.extend([None] * len(s) if w is None else [wk * (scale * mean_scale) for wk in w])
        names.extend([str(p.GetPath())] * len(s))
        index.extend(range(len(s)))
        colors.append(c if c is not None else np.full((len(s), 3), np.nan))
        uniform.append(pv)
    return _assemble(path, strands, widths, colors, names, index, uniform)


def _assemble(path, strands, widths, colors, names, index, uniform) -> UsdCurves:
    from ..rods.groom import Groom
    try:
        groom = Groom.from_polylines(strands)
    except ValueError as exc:
        raise HairFileError(f"{path}: the curves do not make a groom: {exc} (strand s is curve "
                            f"curve_index[s] of prim prims[s])") from None
    has_widths = any(w is not None for w in widths)
    widths = [np.full(len(x), np.nan) if w is None else w for x, w in zip(strands, widths)] if has_widths else None
    colors = np.concatenate(colors)
    colors = None if np.isnan(colors).all() else colors
    common = set.intersection(*(set(pv) for pv in uniform)) if uniform else set()
    primvars = {}
    for name in sorted(common):
        try:
            primvars[name] = np.concatenate([pv[name] for pv in uniform])
        except ValueError:
            continue  # shapes differ between prims: leave it out
    return UsdCurves(groom, widths, colors, names, np.asarray(index, dtype=np.int64), primvars)


def _curve_prims(stage, path, prim, UsdGeom):
    if prim is not None:
        p = stage.GetPrimAtPath(str(prim))
        if not p.IsValid():
            raise HairFileError(f"{path}: no prim at {prim}")
        if not p.IsA(UsdGeom.BasisCurves):
            raise HairFileError(f"{path}: prim {prim} is a {p.GetTypeName() or 'typeless prim'}, "
                                f"not BasisCurves")
        return [p]
    prims = [p for p in stage.Traverse() if p.IsA(UsdGeom.BasisCurves)]
    if not prims:
        raise HairFileError(f"{path}: no BasisCurves prim in the file (prim: none found under "
                            f"{stage.GetPseudoRoot().GetPath()})")
    return prims


def _read_prim(p, path, code, n_nodes, UsdGeom):
    """(strands [list of [N, 3] local points], widths [list of [N]] or None, colours [C, 3] or None,
    uniform primvars {name: [C, ...]}) for one BasisCurves prim."""
    curves = UsdGeom.BasisCurves(p)
    where = f"{path}: prim {p.GetPath()}"
    points = curves.GetPointsAttr().Get(code)
    counts = curves.GetCurveVertexCountsAttr().Get(code)
    if points is None or counts is None or len(counts) == 0:
        raise HairFileError(f"{where}: no points or curveVertexCounts")
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    counts = np.asarray(counts, dtype=np.int64)
    if (counts < 0).any() or counts.sum() != len(points):
        raise HairFileError(f"{where}: curveVertexCounts add up to {counts.sum()}, but there are "
                            f"{len(points)} points")
    bad = np.flatnonzero(~np.isfinite(points).all(axis=1))
    if len(bad):
        curve = int(np.searchsorted(np.cumsum(counts), bad[0], side="right"))
        raise HairFileError(f"{where}: non-finite (NaN or inf) point {bad[0]} in curve {curve}")
    problem = coordinate_problem(points, "point")
    if problem:
        raise HairFileError(f"{where}: {problem}")
    kind, basis, wrap = (str(curves.GetTypeAttr().Get()), str(curves.GetBasisAttr().Get()),
                         str(curves.GetWrapAttr().Get()))
    if wrap == "periodic":
        raise HairFileError(f"{where}: periodic (closed) curves are not hair; only nonperiodic and pinned")
    if kind == "cubic" and basis not in CUBIC_BASES:
        raise HairFileError(f"{where}: unsupported cubic basis {basis!r}")
    minimum = 4 if kind == "cubic" and wrap != "pinned" else 3
    short = np.flatnonzero(counts < minimum)
    if len(short):
        raise HairFileError(f"{where}: curve {short[0]} has {counts[short[0]]} points; at least "
                            f"{minimum} are needed ({kind}{' ' + basis if kind == 'cubic' else ''}, {wrap})")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    cvs = [points[a: a + n] for a, n in zip(starts, counts)]
    widths = _vertex_values(curves.GetWidthsAttr().Get(code), curves.GetWidthsInterpolation(),
                            counts, starts, (kind, basis, wrap), where, "widths")
    if kind == "cubic":
        segs = [_segments(n, basis, wrap, where, c) for c, n in enumerate(counts)]
        nodes = [n_nodes or 3 * k + 1 for k in segs]
        strands = [_evaluate(cv, basis, wrap, m) for cv, m in zip(cvs, nodes)]
        if widths is not None:
            widths = [_evaluate_widths(w, n, basis, wrap, m, interp)
                      for (w, interp), n, m in zip(widths, counts, nodes)]
    else:
        strands = cvs
        widths = None if widths is None else [w for w, _ in widths]
    if widths is not None:
        flat = np.concatenate(widths)
        bad = np.flatnonzero(~(np.isfinite(flat) & (flat > 0)))
        if len(bad):
            curve = int(np.searchsorted(np.cumsum([len(w) for w in widths]), bad[0], side="right"))
            raise HairFileError(f"{where}: width {float(flat[bad[0]])!r} of curve {curve}; widths must be "
                                f"finite and > 0")
    colors, uniform = _curve_primvars(p, code, counts, starts, where, UsdGeom)
    return strands, widths, colors, uniform


def _vertex_values(values, interpolation, counts, starts, curve_type, where, name):
    """Per-curve ([values], interpolation) or None: constant / uniform values repeated per vertex."""
    if values is None or len(values) == 0:
        return None
    values = np.asarray(values, dtype=np.float64)
    kind, basis, wrap = curve_type
    n = len(counts)
    if interpolation == "constant" or len(values) == 1:
        return [(np.full(c, values[0]), "vertex") for c in counts]
    if interpolation == "uniform" and len(values) == n:
        return [(np.full(c, values[k]), "vertex") for k, c in enumerate(counts)]
    if interpolation in ("vertex", "varying") and len(values) == counts.sum() and (kind != "cubic" or interpolation == "vertex"):
        return [(values[a: a + c], "vertex") for a, c in zip(starts, counts)]
    if interpolation == "varying" and kind == "cubic":
        ends = [_segments(c, basis, wrap, where, k) + 1 for k, c in enumerate(counts)]
        if sum(ends) == len(values):
            offs = np.concatenate([[0], np.cumsum(ends)[:-1]])
            return [(values[a: a + e], "varying") for a, e in zip(offs, ends)]
    raise HairFileError(f"{where}: {len(values)} {name} do not fit interpolation {interpolation!r} "
                        f"for {n} curves of {counts.sum()} points")


def _curve_primvars(p, code, counts, starts, where, UsdGeom):
    """(per-curve displayColor [C, 3] or None, {name: [C, ...]} other uniform/constant primvars)."""
    colors, uniform = None, {}
    for pv in UsdGeom.PrimvarsAPI(p).GetPrimvars():
        value = pv.Get(code)
        if value is None:
            continue
        interp, name = pv.GetInterpolation(), pv.GetPrimvarName()
        try:
            value = np.asarray(value)
        except Exception:
            continue
        if value.dtype == object or value.ndim == 0 or len(value) == 0:
            continue
        if interp == "constant":
            per_curve = np.repeat(value[:1], len(counts), axis=0)
        elif interp == "uniform" and len(value) == len(counts):
            per_curve = value
        elif interp in ("vertex", "varying") and len(value) == counts.sum():
            per_curve = value[starts]
        else:
            continue
        if name == "displayColor":
            colors = per_curve.astype(np.float64).reshape(len(counts), 3)
        elif interp in ("constant", "uniform"):
            uniform[str(name)] = per_curve
    return colors, uniform


def _segments(n, basis, wrap, where, curve) -> int:
    """Cubic segments of a curve of n control points."""
    if basis == "bezier":
        if (n - 1) % 3:
            raise HairFileError(f"{where}: bezier curve {curve} has {n} points; a nonperiodic bezier "
                                f"needs 3 k + 1")
        return (n - 1) // 3
    return n - 1 if wrap == "pinned" else n - 3


_BASIS = {  # (4, 4) coefficient matrices: weights(t) = [1, t, t^2, t^3] @ M
    "bezier": np.array([[1, 0, 0, 0], [-3, 3, 0, 0], [3, -6, 3, 0], [-1, 3, -3, 1]], dtype=np.float64),
    "bspline": np.array([[1, 4, 1, 0], [-3, 0, 3, 0], [3, -6, 3, 0], [-1, 3, -3, 1]], dtype=np.float64) / 6.0,
    "catmullRom": np.array([[0, 2, 0, 0], [-1, 0, 1, 0], [2, -5, 4, -1], [-1, 3, -3, 1]], dtype=np.float64) / 2.0,
}


def _evaluate(cv, basis, wrap, n_nodes):
    """[n_nodes, D] points of the cubic curve with control points cv [n, D], evenly in parameter."""
    cv = np.asarray(cv, dtype=np.float64)
    if cv.ndim == 1:
        cv = cv[:, None]
    if wrap == "pinned" and basis != "bezier":  # phantom end points: the curve passes through both ends
        cv = np.concatenate([2 * cv[:1] - cv[1:2], cv, 2 * cv[-1:] - cv[-2:-1]])
    step = 3 if basis == "bezier" else 1
    k = (len(cv) - 1) // 3 if basis == "bezier" else len(cv) - 3
    u = np.linspace(0.0, k, n_nodes)
    seg = np.minimum(np.floor(u).astype(np.int64), k - 1)
    t = u - seg
    weights = np.stack([np.ones_like(t), t, t * t, t * t * t], axis=1) @ _BASIS[basis]  # [n_nodes, 4]
    idx = seg[:, None] * step + np.arange(4)
    return np.einsum("nj,njd->nd", weights, cv[idx])


def _evaluate_widths(w, n, basis, wrap, n_nodes, interpolation):
    if interpolation == "varying":  # one width per segment end, linear in parameter
        return np.interp(np.linspace(0.0, len(w) - 1, n_nodes), np.arange(len(w)), w)
    return _evaluate(w, basis, wrap, n_nodes)[:, 0]
