"""USD hair out: animated linear BasisCurves written frame by frame, crash-safe (the format is
described in taichi_hair.hair.usd's docstring)."""

import os
from pathlib import Path

import numpy as np

from .hairfile import HairFileError
from .usd_pxr import require_pxr


def _strand_list(strands, what):
    """List of [N_i, 3] float arrays from an [S, N, 3] array or a list of [N_i, 3] arrays."""
    if isinstance(strands, np.ndarray) and strands.ndim == 3:
        out = list(strands)
    elif isinstance(strands, (list, tuple)):
        out = [np.asarray(x) for x in strands]
    else:
        raise ValueError(f"{what} must be an [S, N, 3] array or a list of [N_i, 3] arrays, got "
                         f"{type(strands).__name__}")
    if not out or any(x.ndim != 2 or x.shape[1] != 3 or len(x) < 2 for x in out):
        raise ValueError(f"{what} must hold at least one strand, each [N_i >= 2, 3]")
    return out


class UsdCurvesWriter:
    """A USD file of animated linear BasisCurves, written frame by frame and crash-safe.

    path: the target (`.usdc` binary, `.usda` text, `.usd` binary). fps: frames per second
    (timeCodesPerSecond). head_mesh: optional (vertices [V, 3] m, triangles [F, 3]) written once
    as /Head/Mesh; `write_frame(head_pose=(R, t))` animates /Head's transform.
    Curve sets (e.g. "Guides", "Dense") become /Hair/<name>; each is defined on its first frame
    (counts, widths [m] scalar or per node, colours [3] or [S, 3] sRGB, `define`), and every
    later frame must keep its counts. After every `write_frame` the whole stage is exported to
    `<stem>.tmp<suffix>` and renamed over `path`.
    `resume=n` reopens an existing file written by this class and keeps its time codes < n
    (later ones, from a frame that was written but not checkpointed, are dropped); it raises
    ValueError when the file is missing or holds fewer frames."""

    def __init__(self, path, fps, *, head_mesh=None, resume=None, first_time_code=1):
        self.Usd, self.UsdGeom, self.Sdf, self.Vt, self.Gf = require_pxr()
        self.path = Path(path)
        if self.path.suffix not in (".usd", ".usdc", ".usda"):
            raise ValueError(f"USD path must end in .usdc, .usda or .usd, got {self.path}")
        if not (isinstance(fps, (int, float, np.integer, np.floating)) and fps > 0):
            raise ValueError(f"fps must be > 0, got {fps!r}")
        self.fps = float(fps)
        self.first = float(first_time_code)
        self.counts, self._half_width = {}, {}
        layer = self.Sdf.Layer.CreateAnonymous(self.path.suffix)
        if resume is not None:
            self._reopen(layer, int(resume))
        self.stage = self.Usd.Stage.Open(layer)
        if resume is None:
            self._setup(head_mesh)

    def _setup(self, head_mesh):
        stage, UsdGeom = self.stage, self.UsdGeom
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
        stage.SetTimeCodesPerSecond(self.fps)
        stage.SetFramesPerSecond(self.fps)
        stage.SetStartTimeCode(self.first)
        stage.SetEndTimeCode(self.first)
        root = UsdGeom.Xform.Define(stage, "/Hair")
        stage.SetDefaultPrim(root.GetPrim())
        if head_mesh is not None:
            vertices, faces = (np.asarray(a) for a in head_mesh)
            UsdGeom.Xform.Define(stage, "/Head").AddTransformOp()
            mesh = UsdGeom.Mesh.Define(stage, "/Head/Mesh")
            mesh.CreatePointsAttr(self.Vt.Vec3fArray.FromNumpy(vertices.astype(np.float32)))
            mesh.CreateFaceVertexCountsAttr(self.Vt.IntArray.FromNumpy(np.full(len(faces), faces.shape[1], np.int32)))
            mesh.CreateFaceVertexIndicesAttr(self.Vt.IntArray.FromNumpy(faces.astype(np.int32).ravel()))
            mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
            mesh.CreateExtentAttr([tuple(map(float, vertices.min(0))), tuple(map(float, vertices.max(0)))])
            mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set([(0.8, 0.65, 0.55)])

    def _reopen(self, layer, frames_done):
        if not self.path.is_file():
            raise ValueError(f"{self.path}: the USD file of the run to resume is missing; delete the "
                             f"output folder to start over")
        try:
            layer.TransferContent(self.Sdf.Layer.OpenAsAnonymous(str(self.path)))
        except Exception as exc:
            raise ValueError(f"{self.path}: not a readable USD file ({' '.join(str(exc).split())[:200]}); "
                             f"delete the output folder to start over") from None
        last = self.first + frames_done - 1
        stage = self.Usd.Stage.Open(layer)
        for prim in stage.Traverse():
            for attr in prim.GetAttributes():
                for code in attr.GetTimeSamples():
                    if code > last + 1e-9:
                        attr.ClearAtTime(code)
            if prim.IsA(self.UsdGeom.BasisCurves):
                counts = self.UsdGeom.BasisCurves(prim).GetCurveVertexCountsAttr().Get()
                self.counts[prim.GetName()] = np.asarray(counts, dtype=np.int64)
        held = max((c for p in stage.Traverse() if p.IsA(self.UsdGeom.BasisCurves)
                    for c in self.UsdGeom.BasisCurves(p).GetPointsAttr().GetTimeSamples()), default=None)
        if frames_done > 0 and (held is None or held < last - 1e-9):
            raise ValueError(f"{self.path}: holds frames up to time code {held}, the checkpoint says "
                             f"{frames_done} frames (to {last:g}) are done; delete the output folder to start over")
        stage.SetEndTimeCode(max(last, self.first))

    def define(self, name, counts, *, widths=1.5e-4, colours=(0.28, 0.17, 0.09)):
        """Define /Hair/<name>: linear curves of `counts` nodes, widths [m] (scalar, [S] or per node
        [sum(counts)]), colours [3] or [S, 3] (displayColor, one per curve)."""
        counts = np.asarray(counts, dtype=np.int64)
        n = int(counts.sum())
        curves = self.UsdGeom.BasisCurves.Define(self.stage, f"/Hair/{name}")
        curves.CreateTypeAttr(self.UsdGeom.Tokens.linear)
        curves.CreateWrapAttr(self.UsdGeom.Tokens.nonperiodic)
        curves.CreateCurveVertexCountsAttr(self.Vt.IntArray.FromNumpy(counts.astype(np.int32)))
        w = np.asarray(widths, dtype=np.float32)
        w = np.broadcast_to(w, (n,)) if w.ndim == 0 else (np.repeat(w, counts) if w.shape == (len(counts),) else w)
        if w.shape != (n,) or not np.isfinite(w).all():
            raise ValueError(f"widths must be a finite scalar, [S] or [sum(counts)] array, got shape {w.shape}")
        curves.CreateWidthsAttr(self.Vt.FloatArray.FromNumpy(np.ascontiguousarray(w)))
        curves.SetWidthsInterpolation(self.UsdGeom.Tokens.vertex)
        c = np.broadcast_to(np.asarray(colours, dtype=np.float32), (len(counts), 3))
        curves.CreateDisplayColorPrimvar(self.UsdGeom.Tokens.uniform).Set(
            self.Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(c)))
        self.counts[name] = counts
        self._half_width[name] = float(w.max()) / 2

    def write_frame(self, time_code, curves, head_pose=None, save=True):
        """Points of every curve set at `time_code`: curves {name: [S, N, 3] array or list of
        [N_i, 3]} (m); sets not defined yet are defined with the default style. head_pose: (R [3, 3],
        t [3]) of the head. Then the file is saved atomically (unless save=False)."""
        code = float(time_code)
        for name, strands in curves.items():
            strands = _strand_list(strands, f"curves[{name!r}]")
            counts = np.array([len(x) for x in strands], dtype=np.int64)
            if name not in self.counts:
                self.define(name, counts)
            elif not np.array_equal(counts, self.counts[name]):
                raise ValueError(f"curves[{name!r}]: the strand counts changed since the first frame")
            points = np.ascontiguousarray(np.concatenate(strands).astype(np.float32))
            prim = self.UsdGeom.BasisCurves(self.stage.GetPrimAtPath(f"/Hair/{name}"))
            prim.GetPointsAttr().Set(self.Vt.Vec3fArray.FromNumpy(points), code)
            lo, hi = points.min(0), points.max(0)
            if name not in self._half_width:
                self._half_width[name] = float(np.max(np.asarray(prim.GetWidthsAttr().Get(), dtype=np.float64))) / 2
            pad = self._half_width[name]
            prim.GetExtentAttr().Set([tuple(map(float, lo - pad)), tuple(map(float, hi + pad))], code)
        head = self.stage.GetPrimAtPath("/Head")
        if head_pose is not None and head.IsValid():
            rotation, translation = (np.asarray(a, dtype=np.float64) for a in head_pose)
            m = np.eye(4)
            m[:3, :3], m[3, :3] = rotation.T, translation  # USD: row vectors, p' = p M
            op = self.UsdGeom.Xformable(head).GetOrderedXformOps()[0]
            op.Set(self.Gf.Matrix4d(m.tolist()), code)
        self.stage.SetStartTimeCode(min(self.stage.GetStartTimeCode(), code))
        self.stage.SetEndTimeCode(max(self.stage.GetEndTimeCode(), code))
        if save:
            self.save()

    def save(self):
        """Export the stage to a temporary file beside `path` and rename it over `path`."""
        tmp = self.path.with_name(f"{self.path.stem}.tmp{self.path.suffix}")
        if self.path.is_dir():
            raise HairFileError(f"{self.path}: cannot write the USD file: a folder of that name is in the way")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            ok = self.stage.GetRootLayer().Export(str(tmp))
            if ok:
                os.replace(tmp, self.path)
        except Exception as exc:
            tmp.unlink(missing_ok=True)
            raise HairFileError(f"{self.path}: cannot write ({' '.join(str(exc).split())[:200]})") from None
        if not ok:
            tmp.unlink(missing_ok=True)
            raise HairFileError(f"{self.path}: cannot write the USD file")


def _ndim(x) -> int:
    """Dimensions of x as an array; 0 for a ragged list (a frame of strands of unequal lengths)."""
    try:
        return np.asarray(x).ndim
    except ValueError:
        return 0


def write_usd_curves(path, frames, times=None, *, fps=24, widths=1.5e-4, colours=(0.28, 0.17, 0.09),
                     name="Strands", head_mesh=None, head_poses=None):
    """Write animated strands as /Hair/<name> (linear BasisCurves) to a USD file.

    frames: a list of frames, each an [S, N, 3] array or a list of [N_i, 3] arrays (m), the same
        counts every frame; or one such frame (a still groom, written at time code 0 when times
        is None). An [F, S, N, 3] array works too.
    times: [F] seconds (time code = time * fps); default frame k at time code k + 1.
    widths [m]: scalar, [S] or per node; colours: [3] or [S, 3]. head_mesh (V, F) and
    head_poses [F] of (R, t): the head as /Head/Mesh with an animated transform."""
    if isinstance(frames, np.ndarray) and frames.ndim == 3 or (
            isinstance(frames, (list, tuple)) and frames and _ndim(frames[0]) == 2):
        frames, times = [frames], ([0.0] if times is None else times)
    frames = list(frames)
    codes = (np.arange(1, len(frames) + 1, dtype=np.float64) if times is None
             else np.asarray(times, dtype=np.float64) * fps)
    if codes.shape != (len(frames),) or not np.isfinite(codes).all():
        raise ValueError(f"times must be {len(frames)} finite seconds, got {times!r}")
    if head_poses is not None and len(head_poses) != len(frames):
        raise ValueError(f"head_poses must hold one (R, t) per frame ({len(frames)}), got {len(head_poses)}")
    writer = UsdCurvesWriter(path, fps, head_mesh=head_mesh, first_time_code=float(codes.min()))
    first = _strand_list(frames[0], "frames[0]")
    writer.define(name, [len(x) for x in first], widths=widths, colours=colours)
    for k, (frame, code) in enumerate(zip(frames, codes)):
        writer.write_frame(code, {name: frame}, None if head_poses is None else head_poses[k], save=False)
    writer.save()
    return writer.path
