"""Per-frame meshes of a resynthesis: OBJ or PLY files (with the subject's texture), or one
``.npz``."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from faceanalysis.resynthesis.options import MESH_FORMATS
from faceanalysis.resynthesis.personalize import SubjectInfo
from faceanalysis.resynthesis.series import FrameState, Series

log = logging.getLogger(__name__)



class MeshExporter:
    """Per-frame OBJ/PLY files in a folder, or one ``.npz`` of vertex trajectories."""

    def __init__(self, target, fmt: str, model, overwrite: bool,
                 subject: SubjectInfo | None = None):
        if fmt not in MESH_FORMATS:
            raise ValueError(f"unknown mesh format {fmt!r}; choose from {', '.join(MESH_FORMATS)}")
        self.target = Path(target)
        self.npz = self.target.suffix.lower() == ".npz"
        self.fmt = fmt
        self.model_mesh = model.mesh
        self.written: list[Path] = []
        self.vertices: list[np.ndarray] = []
        self.inner: list[np.ndarray] = []
        self.frames: list[int] = []
        self.subject_uv = subject.uv()[0] if subject is not None else None
        if self.npz:
            if self.target.exists() and not overwrite:
                raise FileExistsError(f"{self.target} exists; pass --overwrite "
                                      f"(overwrite=True) to replace it")
        else:
            from faceanalysis.io.outputs import prepare_output_dir

            prepare_output_dir(self.target, overwrite=overwrite)
            if subject is not None and fmt == "obj":
                self._write_material(subject)

    def _write_material(self, subject: SubjectInfo) -> None:
        """The subject's neutral frame as the texture of the OBJ files (``subject.mtl``)."""
        import cv2

        from faceanalysis.io.outputs import atomic_path, write_text_atomic

        with atomic_path(self.target / "subject_texture.png") as tmp:
            if not cv2.imwrite(str(tmp), cv2.cvtColor(subject.image, cv2.COLOR_RGB2BGR)):
                raise ValueError(f"could not write {self.target / 'subject_texture.png'}")
        write_text_atomic(self.target / "subject.mtl",
                          "newmtl skin\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\n"
                          "map_Kd subject_texture.png\n")

    def _write_obj(self, path: Path, vertices: np.ndarray) -> None:
        """OBJ of the skin with the subject's texture coordinates (neutral-frame projection)."""
        from faceanalysis.io.outputs import write_text_atomic

        mesh = self.model_mesh
        t = np.asarray(mesh.triangles) + 1
        uv = self.subject_uv
        lines = ["# faceanalysis resynthesis, personalised skin (cm; x = subject's left, "
                 "y = up, z = toward the viewer)", "mtllib subject.mtl"]
        lines += [f"v {a:.6f} {b:.6f} {c:.6f}" for a, b, c in vertices]
        lines += [f"vt {a:.6f} {1.0 - b:.6f}" for a, b in uv]
        lines.append("usemtl skin")
        lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in t]
        write_text_atomic(path, "\n".join(lines) + "\n")

    def add(self, st: FrameState, model) -> None:
        self.frames.append(st.frame)
        if self.npz:
            self.vertices.append(st.vertices.astype(np.float32))
            self.inner.append(np.asarray(st.inner, np.float32))
            return
        path = self.target / f"frame_{st.frame:06d}.{self.fmt}"
        if self.fmt == "obj" and self.subject_uv is not None:
            self._write_obj(path, st.vertices)
        else:
            (model.to_obj if self.fmt == "obj" else model.to_ply)(path)
        self.written.append(path)

    def finish(self, series: Series) -> Path:
        if not self.npz:
            return self.target
        from faceanalysis.io.outputs import atomic_path

        mesh = self.model_mesh
        with atomic_path(self.target) as tmp, open(tmp, "wb") as fh:
            np.savez_compressed(
                fh, vertices=np.stack(self.vertices), inner_vertices=np.stack(self.inner),
                triangles=np.asarray(mesh.triangles, np.int32),
                inner_triangles=np.asarray(mesh.inner_triangles, np.int32),
                uv=np.asarray(mesh.uv, np.float32), frames=np.asarray(self.frames),
                timestamps=series.timestamps[: len(self.frames)],
                units=np.array("cm; x = subject's left, y = up, z = toward the viewer"),
                **({} if self.subject_uv is None else
                   {"subject_uv": self.subject_uv.astype(np.float32)}))
        return self.target

    def abort(self) -> None:
        self.vertices.clear()
        self.inner.clear()
