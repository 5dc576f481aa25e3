"""Headless renderer of the face model with exact ground truth.

- :mod:`~synth.render.camera`: orthographic / perspective cameras, head pose, ``project``;
- :mod:`~synth.render.raster`: Numba z-buffer (triangle ids + barycentrics), normals, shading
  and flow kernels;
- :mod:`~synth.render.renderer`: :class:`Renderer` / :class:`RenderResult`;
- :mod:`~synth.render.texture`: procedural skin texture per identity seed;
- :mod:`~synth.render.groundtruth`: exact dense flow with occlusion, fiducials, head frame;
- :mod:`~synth.render.sequence`: synthetic videos with ground-truth files;
- :mod:`~synth.render.video`: video writer (mp4, falling back to avi).
"""

from synth.render.camera import Camera, HeadPose, default_camera, project
from synth.render.groundtruth import (
    flow_and_occlusion,
    forward_flow,
    head_frame,
    project_landmarks,
    warp_backward,
)
from synth.render.renderer import Renderer, RenderResult, Surface
from synth.render.sequence import SyntheticSequence, render_sequence, synthesize, write_sequence
from synth.render.shading import Light
from synth.render.texture import paint_skin_texture, texture_params

__all__ = ["Camera", "HeadPose", "default_camera", "project", "Renderer", "RenderResult",
           "Surface", "Light", "paint_skin_texture", "texture_params", "forward_flow",
           "flow_and_occlusion", "head_frame", "project_landmarks", "warp_backward",
           "SyntheticSequence", "synthesize", "render_sequence", "write_sequence"]
