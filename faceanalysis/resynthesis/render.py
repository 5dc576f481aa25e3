"""Resynthesis: drive the face model with a contraction time series and render it again.

004 closes its loop by feeding the estimated contractions to the face model (Fig. 7c): "the
model quickly attains dynamic equilibrium on each frame input". :func:`resynthesize` does the
same for a ``contractions.csv`` (or an :class:`~faceanalysis.analysis.pipeline.Analysis`, or an
analysis folder): every frame sets the muscle contractions and the jaw, relaxes the tissue
lattice to equilibrium (warm-started from the previous frame's) and renders it.

Framing. When the series carries head frames (``head_x, head_y, head_scale, head_roll``) and
the input's frame size is known (``analysis.json``), the frontal view places the model in the
input's framing: the model's own head reference frame (the hairline centroid and the nostrils,
:func:`synth.personalize.head_frame_points`) is mapped onto the tracked head frame of each
frame by a similarity (orthographic scale, in-plane roll, translation), so the resynthesis
moves with the head. Otherwise a fixed camera frames the face.

Personalisation (``subject=``). The generic model is deformed to the subject's neutral frame
by a landmark-driven warp of the whole structure (Kähler 001, ch. 8;
:mod:`synth.personalize`): the 11 neutral fiducials (taken from the image into model space by
the neutral frame's similarity; their unobserved depth is the model's, scaled by the
subject's overall size in the image plane), the hairline centroid and the nostrils (pinned:
they define the framing) drive a 3-D radial-basis interpolation. Should the warp fold space
or leave a muscle without tissue to pull, it is blended toward the best affine map of the
landmarks until the model is valid (a warning says so; the landmark error in the report
shows the cost). The
personalised model is textured with the neutral frame itself, projected through the
framing (uv = image position / image size), and rendered unlit, so that its neutral frame
reproduces the input and its expressions move the subject's own skin.

Lost frames (``success == 0``) hold the last good contractions and head frame.
"""

from __future__ import annotations

import logging
import math
import sys
import time
from pathlib import Path

import numpy as np

from faceanalysis.io.table import FIDUCIALS, JAW, MUSCLES
from faceanalysis.resynthesis.export import MeshExporter
from faceanalysis.resynthesis.framing import (
    framing_from_head,
    head_reference,
    rotation_2d,
    transfer_head_motion,
)
from faceanalysis.resynthesis.options import VIEWS
from faceanalysis.resynthesis.personalize import SubjectInfo
from faceanalysis.resynthesis.series import FrameState, Series, same_path

log = logging.getLogger(__name__)



# ----------------------------------------------------------------------------- drawing
class _Wireframe:
    """Wireframe of the skin with the muscles drawn over it (004, Fig. 4)."""

    def __init__(self, model):
        from synth.muscles import uv_to_surface

        mesh = model.mesh
        self.tris = np.asarray(mesh.triangles, dtype=np.int64)
        n = len(mesh.vertices)
        eye = np.eye(n)
        self.names = list(model.muscle_names)
        self.parts = []     # per muscle: (kind, weight matrix (k, N), fixed points or None)
        for m in model.muscles.muscles:
            p = m.params
            if m.type == "linear":
                uv = np.array([p["head"], p["tail"]], float)
                self.parts.append(("line", uv_to_surface(mesh, uv, values=eye)))
            elif m.type == "sphincter":
                a, b = p["semi_axes"]
                ang = math.radians(p.get("angle", 0.0))
                t = np.linspace(0, 2 * np.pi, 25)
                e = (np.c_[a * np.cos(t), b * np.sin(t)] @ rotation_2d(ang).T
                     + np.asarray(p["centre"]))
                self.parts.append(("loop", uv_to_surface(mesh, e, values=eye)))
            else:
                (a1, a2), (i1, i2) = p["attachment"], p["insertion"]
                uv = np.array([a1, a2, i2, i1, a1], float)
                self.parts.append(("loop", uv_to_surface(mesh, uv, values=eye)))

    def draw(self, xy_skin: np.ndarray, contractions: np.ndarray, size) -> np.ndarray:
        import cv2

        W, H = size
        img = np.empty((H, W, 3), np.uint8)
        img[:] = (18, 22, 30)
        p = xy_skin[self.tris]
        a = p[:, 1] - p[:, 0]
        b = p[:, 2] - p[:, 0]
        front = -(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]) > 0
        sh = 4
        pts = np.round(p[front] * (1 << sh)).astype(np.int32)
        cv2.polylines(img, list(pts), True, (120, 150, 140), 1, cv2.LINE_AA, sh)
        for (kind, Wm), c in zip(self.parts, contractions):
            q = np.round((Wm @ xy_skin) * (1 << sh)).astype(np.int32)
            colour = (int(110 + 145 * c), int(60 * (1 - c)), int(60 * (1 - c)))
            thick = 1 + int(round(2 * c))
            cv2.polylines(img, [q], kind == "loop", colour, thick, cv2.LINE_AA, sh)
            if kind == "line":
                cv2.circle(img, tuple(int(v) for v in q[0]), 2 << sh, colour, -1,
                           cv2.LINE_AA, sh)
        return img


class _PlotStrip:
    """The contraction plot under a side-by-side video, with a moving cursor."""

    def __init__(self, times, controls, jaw, width: int, height: int):
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        series = {MUSCLES[j]: controls[:, j] for j in range(controls.shape[1])}
        series[JAW + " (x2, rad)"] = 2 * jaw
        active = sorted(((float(np.nanmax(v)), k) for k, v in series.items()
                         if np.nanmax(v) > 0.02), reverse=True)[:6]
        dpi = 100
        fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi)
        FigureCanvasAgg(fig)      # an off-screen canvas: the global backend stays as it is
        ax = fig.add_axes((0.06, 0.26, 0.68, 0.68))
        for _, k in active:
            ax.plot(times, series[k], lw=1.2, label=k)
        ax.set_xlim(times[0], times[-1] if times[-1] > times[0] else times[0] + 1)
        ax.set_ylim(0, 1.02)
        ax.tick_params(labelsize=6)
        ax.set_xlabel("time (s)", fontsize=7, labelpad=1)
        if active:
            ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.05), frameon=False,
                      labelspacing=0.2, handlelength=1.2)
        fig.canvas.draw()
        self.image = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
        bbox = ax.get_window_extent()
        self.y0 = int(round(height - bbox.y1))
        self.y1 = int(round(height - bbox.y0))
        self.xs = ax.transData.transform(np.c_[times, np.zeros_like(times)])[:, 0]

    def frame(self, i: int) -> np.ndarray:
        import cv2

        img = self.image.copy()
        x = int(round(self.xs[i]))
        cv2.line(img, (x, self.y0), (x, self.y1), (200, 30, 30), 1)
        return img


# ----------------------------------------------------------------------------- main
class Resynthesis:
    """A configured resynthesis: iterate for frames (RGB uint8), or :meth:`write` a video.

    Made by :func:`resynthesize`; see there for the parameters.

    Attributes
    ----------
    model : FaceModel
        The model driven (personalised when a subject was given).
    subject : SubjectInfo or None
    fps : float
    size : (width, height)
        Size of the resynthesised frames (the side-by-side video is wider and taller).
    missing : tuple of str
        Muscles absent from the table (driven at 0).
    report : dict
        Personalisation figures (landmark error, photometric comparison) and, after a run,
        timings.
    path : Path or None
        The video written (after :meth:`write`).
    """

    def __init__(self, series: Series, *, model, subject: SubjectInfo | None, size, view,
                 shading, fps, side_by_side, input_video, tol):
        self.series = series
        self.subject = subject
        self.model = subject.model if subject is not None else model
        self.view = view
        self.shading = shading
        self.fps = series.fps(fps)
        self.side_by_side = side_by_side
        self.tol = float(tol)
        self.missing = series.missing
        self.path: Path | None = None
        self.report: dict = {}
        self.report_path: Path | None = None      # the report written beside the video
        in_size = series.input_size
        if subject is not None:
            in_size = (subject.image.shape[1], subject.image.shape[0])
        self.input_size = in_size
        # output size
        if size is None:
            size = (in_size[0] if in_size is not None and view == "front" else 256)
        if isinstance(size, (int, np.integer)):
            if in_size is not None and view == "front":
                w = int(size)
                h = max(16, int(round(size * in_size[1] / in_size[0])))
            else:
                w = h = int(size)
        else:
            w, h = (int(v) for v in size)
        if w < 16 or h < 16:
            raise ValueError(f"size {w}x{h} must be at least 16x16")
        self.size = (w, h)
        # framing: from the head frames when we know the input's size
        self._framings = None
        if view == "front" and series.heads is not None and in_size is not None:
            heads = series.heads
            if subject is not None:
                origin_cm, scale_cm = subject.reference
                if subject.head is not None and series.success.any():
                    # the source's head motion, relative to its neutral frame, applied to
                    # the subject's neutral head frame (the identity when the subject is the
                    # source's own neutral frame; expression transfer otherwise)
                    heads = transfer_head_motion(heads, heads[series.neutral_row],
                                                 subject.head)
            else:
                origin_cm, scale_cm = head_reference(self.model.mesh)
            f = w / in_size[0]
            self._framings = [framing_from_head(h_, origin_cm, scale_cm).scaled(f)
                              for h_ in heads]
        self.input_video = input_video
        if side_by_side and self.input_video is None:
            self.input_video = (Path(subject.source) if subject is not None and subject.source
                                else series.input_path)
        if side_by_side and (self.input_video is None or not Path(self.input_video).exists()):
            raise ValueError("side_by_side needs the input video: pass input_video (--input) "
                             f"or a source whose analysis.json names it (got "
                             f"{self.input_video})")
        self._renderer = None
        self._wire = None
        self.texture_seed = 0
        self._order = [MUSCLES.index(m) for m in self.model.muscle_names]
        self._background = None
        if subject is not None:
            self.report["personalisation"] = self._personal_report()
            if shading == "textured" and self._framings is not None:
                # the rest of the subject's head (hair, ears, neck) and the scene: the
                # neutral frame, moved with the tracked head frame
                import cv2

                f = w / in_size[0]
                img = cv2.resize(subject.image, (w, h), interpolation=cv2.INTER_AREA)
                self._background = (img, subject.framing.scaled(f))

    # -------------------------------------------------------------- rendering setup
    def _fixed_camera(self):
        from synth.render import HeadPose, default_camera

        w, h = self.size
        cam = default_camera(w, h)
        pose = HeadPose(yaw=VIEWS[self.view], centre=(0.0, -1.6, -1.5))
        return cam, pose

    def _camera_pose(self, row: int):
        if self._framings is not None:
            return self._framings[row].camera_pose(*self.size)
        return self._fixed_camera()

    def _make_renderer(self):
        from synth.render import Renderer, Surface
        from synth.render.shading import Light

        mesh = self.model.mesh
        if self.shading == "wireframe":
            self._wire = _Wireframe(self.model)
            return None
        if self.shading == "plain":
            return Renderer(mesh, camera=self._fixed_camera()[0], supersample=1)
        if self.subject is not None:
            uv, inner_uv = self.subject.uv()
            surf = Surface(vertices=np.asarray(mesh.vertices), triangles=mesh.triangles,
                           uv=np.clip(uv, 0.0, 1.0), inner_vertices=mesh.inner_vertices,
                           inner_triangles=mesh.inner_triangles,
                           inner_material=mesh.inner_material,
                           inner_uv=np.clip(inner_uv, 0.0, 1.0))
            # the photograph already holds the light: render it unlit
            unlit = Light(colour=(1.0, 1.0, 1.0), ambient=1.0, specular_scale=0.0)
            return Renderer(surf, texture=self.subject.image, eye_tex=self.subject.image,
                            camera=self._fixed_camera()[0], light=unlit, supersample=1)
        from synth.render import paint_skin_texture

        tex = paint_skin_texture(mesh, self.texture_seed, size=512)
        return Renderer(mesh, texture=tex, camera=self._fixed_camera()[0], supersample=1)

    def _render(self, skin, inner, row: int, contractions):
        """(image, projected skin xy, skin mask or None) of one frame."""
        from synth.render.camera import project

        cam, pose = self._camera_pose(row)
        if self.shading == "wireframe":
            xy, _ = project(skin, cam, pose)
            return self._wire.draw(xy, contractions, self.size), xy, None
        self._renderer.camera = cam
        res = self._renderer.render(skin, inner, pose=pose)
        image = res.image
        if self._background is not None:
            image = np.where(res.mask[..., None], image, self._moved_background(row))
        return image, res.xy[: len(skin)], res.skin_mask

    def _moved_background(self, row: int) -> np.ndarray:
        """The subject's neutral frame moved by the head motion from neutral to ``row``."""
        import cv2

        img, f0 = self._background
        fi = self._framings[row]
        M = (fi.k / f0.k) * rotation_2d(fi.roll) @ rotation_2d(f0.roll).T
        t = np.asarray(fi.T) - M @ np.asarray(f0.T)
        w, h = self.size
        return cv2.warpAffine(img, np.c_[M, t], (w, h), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REPLICATE)

    def _personal_report(self) -> dict:
        """Landmark error and photometric comparison of the personalised neutral frame."""
        import cv2

        subj = self.subject
        m = self.model
        m.reset()
        m.set_contractions(None)
        m.equilibrate()
        lm = m.landmark_positions()
        pred = subj.framing.apply(np.array([lm[n] for n in FIDUCIALS]))
        err = np.hypot(*(pred - subj.fiducials).T)
        from synth.render import Renderer, Surface
        from synth.render.shading import Light

        H, W = subj.image.shape[:2]
        cam, pose = subj.framing.camera_pose(W, H)
        uv, inner_uv = subj.uv()
        mesh = m.mesh
        surf = Surface(vertices=np.asarray(mesh.vertices), triangles=mesh.triangles,
                       uv=np.clip(uv, 0, 1), inner_vertices=mesh.inner_vertices,
                       inner_triangles=mesh.inner_triangles, inner_material=mesh.inner_material,
                       inner_uv=np.clip(inner_uv, 0, 1))
        r = Renderer(surf, texture=subj.image, eye_tex=subj.image, camera=cam,
                     light=Light(ambient=1.0, specular_scale=0.0))
        res = r.render(m.surface_vertices, m.inner_vertices(), pose=pose)
        mask = cv2.erode(res.skin_mask.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        a = cv2.cvtColor(res.image, cv2.COLOR_RGB2GRAY).astype(float)[mask]
        b = cv2.cvtColor(subj.image, cv2.COLOR_RGB2GRAY).astype(float)[mask]
        ncc = float(np.corrcoef(a, b)[0, 1]) if a.size > 2 and a.std() > 0 and b.std() > 0 \
            else None
        m.reset()
        return {
            "neutral_frame": subj.neutral_frame,
            # (a fiducial not seen on the neutral frame has no error: null)
            "landmark_error_px": {"mean": float(np.nanmean(err)), "max": float(np.nanmax(err)),
                                  "by_point": {n: float(e) if np.isfinite(e) else None
                                               for n, e in zip(FIDUCIALS, err)}},
            "photometric": {"mask_pixels": int(mask.sum()),
                            "mae_grey": float(np.abs(a - b).mean()) if a.size else None,
                            "rmse_grey": float(np.sqrt(np.mean((a - b) ** 2))) if a.size
                            else None, "ncc": ncc},
            "warp": {"landmarks": len(subj.warp.source), "kernel": subj.warp.kernel},
        }

    # -------------------------------------------------------------- iteration
    def states(self, *, progress: bool = False):
        """Iterate :class:`FrameState` objects (equilibrium and rendering of every frame)."""
        s = self.series
        m = self.model
        if self._renderer is None and self._wire is None:
            self._renderer = self._make_renderer()
        m.reset()
        strip = None
        inputs = None
        if self.side_by_side:
            times = s.timestamps if np.isfinite(s.timestamps).all() else s.frames / self.fps
            w, h = self.size
            strip = _PlotStrip(times, s.controls, s.jaw, 2 * w, max(80, int(0.45 * h)))
            inputs = _input_frames(Path(self.input_video), s.frames, self.size)
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=len(s.frames), desc="resynth", unit="frame", file=sys.stderr,
                       leave=False, dynamic_ncols=True)
        prev = None
        lm_idx = [m.mesh.landmarks[n] for n in FIDUCIALS]
        compare = (self.subject is not None and self.shading == "textured"
                   and self._framings is not None)
        # the tracked fiducials in the output's pixel frame (input px scaled like the framing)
        tracked = None
        if self._framings is not None and s.fiducials is not None and self._own_subject():
            tracked = s.fiducials * (self.size[0] / self.input_size[0])
        try:
            for i in range(len(s.frames)):
                t0 = time.perf_counter()
                values = s.controls[i, self._order]
                jaw = float(s.jaw[i])
                key = (values.tobytes(), jaw)
                if key != prev:
                    m.set_contractions(values, jaw_rotation=jaw)
                    m.equilibrate(tol=self.tol)
                    prev = key
                skin = m.surface_vertices
                inner = m.inner_vertices()
                image, xy, mask = self._render(skin, inner, i, values)
                seconds = time.perf_counter() - t0
                out = image
                mae = None
                if self.side_by_side:
                    frame_in = next(inputs)
                    out = np.concatenate([np.concatenate([frame_in, image], axis=1),
                                          strip.frame(i)], axis=0)
                    if compare and s.success[i]:
                        mae = _masked_mae(frame_in, image, mask)
                fids = xy[lm_idx]
                fid_err = None
                if tracked is not None and s.success[i]:
                    d = np.hypot(*(fids - tracked[i]).T)
                    if np.isfinite(d).any():
                        fid_err = float(np.nanmean(d))
                if bar is not None:
                    bar.update(1)
                yield FrameState(row=i, frame=int(s.frames[i]), image=image, output=out,
                                 vertices=skin, inner=inner, fiducials=fids,
                                 seconds=seconds, photometric_mae=mae,
                                 fiducial_error_px=fid_err)
        finally:
            if bar is not None:
                bar.close()
            if inputs is not None:
                inputs.close()

    def __iter__(self):
        for st in self.states():
            yield st.output

    def __len__(self) -> int:
        return len(self.series.frames)

    def __repr__(self) -> str:
        n = len(self)
        on = ("the generic face" if self.subject is None else
              f"{Path(self.subject.source).name if self.subject.source else 'the subject'}'s face")
        written = f" -> {self.path}" if self.path is not None else ""
        return (f"<Resynthesis: {n} frame{'' if n == 1 else 's'} of {self.size[0]}x"
                f"{self.size[1]} at {self.fps:g} fps, {self.view} view, {self.shading}, on "
                f"{on}{written}>")

    def write(self, output, *, export_meshes=None, mesh_format: str = "obj",
              overwrite: bool = False, progress: bool = False) -> Path:
        """Write the video (atomically) and, optionally, the meshes; returns the video path.

        Raises
        ------
        FileExistsError
            ``output`` (or a non-empty ``export_meshes`` folder / file) exists and
            ``overwrite`` is false.
        """

        from synth.render.video import VideoWriter

        output = Path(output)
        if output.exists() and not overwrite:
            raise FileExistsError(f"{output} exists; pass --overwrite (overwrite=True) to "
                                  f"replace it")
        exporter = MeshExporter(export_meshes, mesh_format, self.model, overwrite,
                                 self.subject) if export_meshes is not None else None
        t0 = time.perf_counter()
        times = []
        maes = []
        fid_errors = []
        writer = None
        try:
            for st in self.states(progress=progress):
                if writer is None:
                    h, w = st.output.shape[:2]
                    writer = VideoWriter(output, self.fps, (w, h))
                writer.write(st.output)
                times.append(st.seconds)
                if st.photometric_mae is not None:
                    maes.append(st.photometric_mae)
                if st.fiducial_error_px is not None:
                    fid_errors.append((st.frame, st.fiducial_error_px))
                if exporter is not None:
                    exporter.add(st, self.model)
            self.path = writer.close()
            writer = None
            if exporter is not None:
                self.report["meshes"] = str(exporter.finish(self.series))
        finally:
            if writer is not None:
                writer.abort()
            if exporter is not None:
                exporter.abort()
        if maes:
            self.report["frame_comparison"] = {
                "what": "mean absolute grey-level difference between the input frame and the "
                        "personalised resynthesis on the face mask, tracked frames",
                "frames": len(maes), "mean_mae_grey": float(np.mean(maes)),
                "max_mae_grey": float(np.max(maes))}
        if fid_errors:
            self.report["fiducial_agreement"] = fiducial_agreement(fid_errors)
        elif not self._own_subject():
            self.report["fiducial_agreement"] = {
                "skipped": "the subject is another video than the analysed one: its face's "
                           "features are not the tracked ones"}
        self.report["timing"] = {"frames": len(times), "total_s": time.perf_counter() - t0,
                                 "median_frame_s": float(np.median(times)) if times else None,
                                 "frames_per_second": float(1.0 / np.median(times))
                                 if times else None}
        return self.path


    def _own_subject(self) -> bool:
        """Whether the model is the analysed face's own (generic, or personalised to the
        analysed video): only then do its fiducials answer to the tracked ones. A subject
        from another video plays the series on another face (expression transfer)."""
        if self.subject is None or not self.subject.source or self.series.input_path is None:
            return True
        return same_path(self.subject.source, self.series.input_path)


def _masked_mae(a: np.ndarray, b: np.ndarray, mask) -> float | None:
    """Mean absolute grey difference of two RGB images on ``mask`` (eroded by one pixel)."""
    import cv2

    if mask is None:
        return None
    m = cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    if not m.any():
        return None
    ga = cv2.cvtColor(a, cv2.COLOR_RGB2GRAY).astype(float)
    gb = cv2.cvtColor(b, cv2.COLOR_RGB2GRAY).astype(float)
    return float(np.abs(ga - gb)[m].mean())


def _input_frames(path: Path, frames: np.ndarray, size):
    """Input frames (RGB, resized to ``size``) in step with the table's frame numbers."""
    import cv2

    from faceanalysis.io.frames import to_bgr_uint8
    from faceanalysis.io.video import open_video

    w, h = size
    blank = np.full((h, w, 3), 60, np.uint8)
    with open_video(path, start=int(frames[0]), end=int(frames[-1]) + 1) as src:
        it = iter(src)
        cur = next(it, None)
        for f in frames:
            while cur is not None and cur.index < f:
                cur = next(it, None)
            if cur is not None and cur.index == f and cur.ok:
                img = cv2.cvtColor(to_bgr_uint8(cur.image), cv2.COLOR_BGR2RGB)
                yield cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
            else:
                yield blank


def fiducial_agreement(errors) -> dict:
    """Summary of the resynthesis's fiducials against the tracked ones, for the report.

    Parameters
    ----------
    errors : iterable of (frame, error_px)
        Per tracked frame, the mean distance of the 11 resynthesised fiducials from the
        tracked ones (output pixels; :attr:`FrameState.fiducial_error_px`).

    Returns
    -------
    dict
        ``what``, ``frames``, ``mean_px``, ``median_px``, ``max_px``, ``worst_frame`` and
        ``per_frame`` (a list of ``[frame, error_px]``).

    Examples
    --------
    >>> fiducial_agreement([(0, 1.0), (1, 3.0), (2, 2.0)])["median_px"]
    2.0
    """
    frames = [int(f) for f, _ in errors]
    e = np.array([float(v) for _, v in errors], float)
    if e.size == 0:
        raise ValueError("no frame has both tracked and resynthesised fiducials")
    worst = int(np.argmax(e))
    return {"what": "mean distance of the 11 resynthesised fiducials from the analysis's "
                    "tracked fiducials, output pixels, tracked frames",
            "frames": int(e.size), "mean_px": float(e.mean()),
            "median_px": float(np.median(e)), "max_px": float(e[worst]),
            "worst_frame": frames[worst],
            "per_frame": [[f, round(float(v), 4)] for f, v in zip(frames, e)]}
