"""Renderer: frames/s at 256x256 and 640x480 (one core; procedural, photo-textured), flow EPE.

Frames per second of the headless renderer on the default model's face mesh (and on the
finer resolution-1 mesh), shaded and textured, with and without anti-aliasing, with and
without the exact flow ground truth, measured as medians on one core (Numba kernels are
serial; OpenCV is set to one thread); and of the photo-textured renderer, the face model
fitted to a photograph (an IMM photograph when ``../shared/data`` holds one, else a
procedural face rendered as the photograph). Then a rendered sequence (surprise with head motion
through the physics model when ``synth.model`` is available, else the rest mesh moved by
head motion and jaw rotation only) is given to OpenCV's DIS, Farneback and TV-L1 optical
flow, whose end-point error against the renderer's exact flow is reported on non-occluded
face pixels (eroded by 2 px from the silhouette).
"""

from __future__ import annotations

import cv2
import numpy as np
from _harness import Figure, median_time

NAME = "render"


def _mesh(resolution: float | None = None):
    """The default model's mesh (FaceModel's resolution) or the mesh at ``resolution``."""
    from synth.mesh import generate_face_mesh

    if resolution is None:
        try:
            from synth.model import DEFAULT_RESOLUTION
        except ImportError:
            DEFAULT_RESOLUTION = 1.0
        resolution = DEFAULT_RESOLUTION
    return generate_face_mesh(resolution=resolution), resolution


def _fps_figures(quick: bool) -> list[Figure]:
    from synth.render.camera import HeadPose, default_camera
    from synth.render.groundtruth import flow_and_occlusion
    from synth.render.renderer import Renderer
    from synth.render.texture import paint_skin_texture

    out = []
    repeat = 5 if quick else 15
    number = 3 if quick else 10
    cases = [(None, size, ss) for size in ((256, 256), (640, 480)) for ss in (1, 2)]
    cases += [(1.0, size, 1) for size in ((256, 256), (640, 480))]
    meshes = {}
    for res_req, size, ss in cases:
        if res_req not in meshes:
            meshes[res_req] = _mesh(res_req)
        mesh, res = meshes[res_req]
        tex = paint_skin_texture(mesh, 0)
        v0 = np.asarray(mesh.vertices)
        v1 = v0 + np.random.default_rng(0).normal(0, 0.01, v0.shape)
        pose1 = HeadPose(roll=1.0, yaw=1.0, translation=(0.05, 0.0, 0.0))
        target = {(256, 256): 200.0, (640, 480): 50.0}[size]
        cam = default_camera(*size)
        r = Renderer(mesh, texture=tex, camera=cam, supersample=ss)
        t = median_time(lambda r=r, v0=v0: r.render(v0), repeat=repeat, number=number)
        label = (f"{size[0]}x{size[1]}" + (f" ss{ss}" if ss > 1 else "")
                 + ("" if res_req is None else f" mesh res {res:g}"))
        # the target is for plain shaded, textured frames; supersampled (ss2)
        # frames cost ~4x the shading and are reported without a target
        out.append(Figure(NAME, f"shaded textured {label}", "frames per second", 1.0 / t,
                          "frames/s", True, target=target if ss == 1 else None,
                          extra={"triangles": int(len(r.triangles)),
                                 "mesh_resolution": res, "supersample": ss}))

        def with_flow(r=r, v0=v0, v1=v1, pose1=pose1):
            a = r.render(v0)
            b = r.render(v1, pose=pose1, shade=False)
            flow_and_occlusion(r, a, b)

        t = median_time(with_flow, repeat=repeat, number=number)
        out.append(Figure(NAME, f"shaded textured + flow truth {label}",
                          "frames per second", 1.0 / t, "frames/s", True,
                          extra={"supersample": ss,
                                 "note": "render + next-frame buffers + forward flow + "
                                         "disocclusion"}))
    return out


def _photograph(tmp) -> tuple[str, str]:
    """A frontal neutral photograph to fit: an IMM photograph (person 21, type 1) when
    ``../shared/data`` holds one, else a procedural face rendered at 640x480 and written
    as a png (the figure then measures the same photo-textured renderer on another
    texture). Returns (path, what it is)."""
    import os
    from pathlib import Path

    data = Path(os.environ.get("FACEANALYSIS_REAL_DATA", Path(__file__).resolve().parents[2]
                               / "shared" / "data" / "real")).parent
    imm = sorted((data / "annotated" / "imm_dev").glob("21-1?.jpg"))
    if imm:
        return str(imm[0]), f"IMM photograph {imm[0].name}"
    from synth.render.sequence import synthesize

    seq = synthesize(frames=1, size=(640, 480), seed=1, flow=False)
    path = Path(tmp) / "procedural_face.png"
    cv2.imwrite(str(path), cv2.cvtColor(seq.images[0], cv2.COLOR_RGB2BGR))
    return str(path), "procedural face (seed 1) rendered at 640x480 as the photograph"


def _photo_fps_figures(quick: bool) -> list[Figure]:
    """Frames/s of the photo-textured renderer (:mod:`synth.render.appearance`): the face
    model fitted to a photograph (``photo_face``) and framed like the procedural faces at
    each size, rendered at its equilibrated rest (rendering alone, no physics)."""
    import tempfile

    try:
        from faceanalysis.resynthesis.photo import photo_face
    except ImportError as e:
        print(f"# photo faces unavailable ({e}): photo-textured figures skipped")
        return []
    out = []
    repeat = 5 if quick else 15
    number = 3 if quick else 10
    with tempfile.TemporaryDirectory() as tmp:
        path, source = _photograph(tmp)
        for size in ((256, 256), (640, 480)):
            try:
                face = photo_face(path, size=size)
            except ValueError as e:
                print(f"# {source}: no photo face ({e}): photo-textured figure skipped")
                return out
            model = face.model
            model.reset()
            model.set_contractions(None)
            v = np.asarray(model.equilibrate(), dtype=np.float64)
            iv = np.asarray(model.inner_vertices(), dtype=np.float64)
            pose = face.appearance.pose
            r = face.appearance.renderer(model.mesh, supersample=1)
            t = median_time(lambda r=r, v=v, iv=iv, pose=pose: r.render(v, iv, pose=pose),
                            repeat=repeat, number=number)
            target = {(256, 256): 200.0, (640, 480): 50.0}[size]
            out.append(Figure(NAME, f"photo-textured {size[0]}x{size[1]}",
                              "frames per second", 1.0 / t, "frames/s", True, target=target,
                              extra={"photograph": source, "supersample": 1,
                                     "triangles": int(len(r.triangles)),
                                     "texture": list(face.appearance.texture.shape[:2])}))
    return out


class _JawHeadDriver:
    """Rest mesh opened by a rigid jaw rotation (no muscles): a fallback motion source."""

    def __init__(self, mesh):
        self.mesh = mesh
        self.muscle_names = ()
        self._jaw = 0.0

    def set_contractions(self, values=None, *, jaw_rotation=0.0):
        self._jaw = float(jaw_rotation)

    def _apply(self, pts, w):
        c, s = np.cos(self._jaw), np.sin(self._jaw)
        R = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
        p = np.asarray(self.mesh.jaw_pivot)
        return pts + np.asarray(w)[:, None] * (((pts - p) @ R.T + p) - pts)

    def equilibrate(self, **kw):
        self._v = self._apply(np.asarray(self.mesh.vertices), self.mesh.jaw_weight)
        return self._v

    def inner_vertices(self):
        return self._apply(np.asarray(self.mesh.inner_vertices), self.mesh.inner_jaw_weight)

    def landmark_positions(self):
        return self.mesh.landmark_positions(self._v)


def _sequence(quick: bool):
    import pandas as pd

    from synth.render.sequence import synthesize

    frames = 12 if quick else 30
    try:
        from synth.model import FaceModel  # noqa: F401
    except ImportError:
        model = _JawHeadDriver(_mesh()[0])
        jaw = 0.25 * np.sin(np.linspace(0, np.pi, frames)) ** 2
        seq = synthesize(model=model, contractions=pd.DataFrame({"jaw_rotation": jaw}),
                         frames=frames, seed=3, head_motion=1.0, size=256)
        return seq, "rest mesh + jaw rotation + head motion (synth.model unavailable)"
    seq = synthesize(expression="surprise", frames=frames, seed=3, head_motion=1.0,
                     size=256)
    return seq, "FaceModel (default resolution), surprise + head motion, seed 3, ss2"


def _epe_figures(quick: bool) -> list[Figure]:
    seq, source = _sequence(quick)
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    tvl1 = cv2.optflow.DualTVL1OpticalFlow_create()
    methods = {
        "DIS (medium)": lambda a, b: dis.calc(a, b, None),
        "Farneback": lambda a, b: cv2.calcOpticalFlowFarneback(a, b, None, 0.5, 4, 15, 5, 5,
                                                               1.1, 0),
        "TV-L1": lambda a, b: tvl1.calc(a, b, None),
    }
    errs = {k: [] for k in methods}
    gt_mag = []
    kernel = np.ones((5, 5), np.uint8)
    for t in range(len(seq.images) - 1):
        a = cv2.cvtColor(seq.images[t], cv2.COLOR_RGB2GRAY)
        b = cv2.cvtColor(seq.images[t + 1], cv2.COLOR_RGB2GRAY)
        m = cv2.erode((seq.mask[t] & ~seq.occluded[t]).astype(np.uint8), kernel).astype(bool)
        gt = seq.flow[t]
        gt_mag.append(np.linalg.norm(gt, axis=2)[m].mean())
        for k, fn in methods.items():
            errs[k].append(np.linalg.norm(fn(a, b) - gt, axis=2)[m].mean())
    out = []
    for k, e in errs.items():
        out.append(Figure(NAME, f"EPE {k} vs exact flow, 256x256 face", "end-point error",
                          float(np.mean(e)), "px", False,
                          target=0.5 if k.startswith("DIS") else None,
                          extra={"sequence": source, "frame_pairs": len(e),
                                 "mean_true_flow_px": float(np.mean(gt_mag)),
                                 "max_true_flow_px": float(np.abs(seq.flow).max())}))
    return out


def run(quick: bool = False) -> list[Figure]:
    cv2.setNumThreads(1)
    return _fps_figures(quick) + _photo_fps_figures(quick) + _epe_figures(quick)
