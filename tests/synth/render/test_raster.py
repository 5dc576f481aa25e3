"""Rasterizer, cameras, shading and exact flow on simple meshes (planes, spheres)."""

import numpy as np
import pytest

from synth.render.camera import Camera, HeadPose, default_camera, pose_matrix, project
from synth.render.groundtruth import flow_and_occlusion, forward_flow, warp_backward
from synth.render.raster import rasterize, vertex_normals_fast
from synth.render.renderer import Renderer
from tests.synth.render._meshes import noise_texture, plane, sphere


def test_rasterize_covers_triangle_once_and_exact_barycentrics():
    xy = np.array([[2.3, 1.7], [20.1, 3.2], [8.4, 17.9]])
    z, tid, b = rasterize(xy, np.array([1.0, 2.0, 3.0]), [[0, 1, 2]], 24, 24)
    rr, cc = np.nonzero(tid == 0)
    assert len(rr) > 100
    # barycentrics reproduce the pixel centre
    p = np.einsum("nk,kd->nd", b[rr, cc], xy)
    np.testing.assert_allclose(p, np.stack([cc, rr], 1), atol=1e-9)
    np.testing.assert_allclose(z[rr, cc], b[rr, cc] @ [1.0, 2.0, 3.0])
    assert np.all(np.isinf(z[tid < 0]))


def test_shared_edges_leave_no_gaps():
    s = plane(n=17, size=10.0)
    cam = default_camera(64, 64)
    xy, d = project(s.vertices, cam)
    _, tid, _ = rasterize(xy, d, s.triangles, 64, 64)
    lo = np.ceil(xy.min(0)).astype(int)
    hi = np.floor(xy.max(0)).astype(int)
    assert np.all(tid[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1] >= 0)


def test_zbuffer_keeps_nearest_and_culls_back_faces():
    near = plane(n=2, size=6.0, z=1.0)
    far = plane(n=2, size=10.0, z=-1.0)
    V = np.concatenate([far.vertices, near.vertices])
    T = np.concatenate([far.triangles, near.triangles + 4])
    cam = default_camera(64, 64)
    xy, d = project(V, cam)
    _, tid, _ = rasterize(xy, d, T, 64, 64, cull=np.ones(len(T), bool))
    assert tid[32, 32] >= 2          # the near plane wins in the middle
    assert tid[32, 19] in (0, 1)     # only the far plane out there
    # seen from behind (yaw 180) everything is back-facing and culled
    xy2, d2 = project(V, cam, HeadPose(yaw=180, centre=(0, -2, 0)))
    _, tid2, _ = rasterize(xy2, d2, T, 64, 64, cull=np.ones(len(T), bool))
    assert np.all(tid2 < 0)


def test_project_conventions():
    cam = default_camera(200, 100)
    xy, depth = project([[0, -1.6, 0], [1, -1.6, 0], [0, -0.6, 0], [0, -1.6, 1]], cam)
    c = np.array([99.5, 49.5])
    np.testing.assert_allclose(xy[0], c)
    assert xy[1, 0] > c[0] and xy[2, 1] < c[1]          # +x right, +y up on screen
    assert depth[3] < depth[0]                             # +z toward the camera
    # roll: the model x axis turns clockwise on screen by +roll
    xy_r, _ = project([[0, -2, 0], [1, -2, 0]], cam, HeadPose(roll=30, centre=(0, -2, 0)))
    d = xy_r[1] - xy_r[0]
    assert np.degrees(np.arctan2(d[1], d[0])) == pytest.approx(30)
    R = pose_matrix(HeadPose(roll=10, yaw=20, pitch=-5))
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    # perspective: nearer points are bigger
    pc = default_camera(200, 100, kind="perspective", distance=50)
    a, _ = project([[1, -2, 0], [1, -2, 10]], pc)
    assert a[1, 0] > a[0, 0] > 99.5


def test_camera_validation():
    with pytest.raises(ValueError, match="kind"):
        Camera(kind="fisheye")
    with pytest.raises(ValueError, match="shape"):
        project(np.zeros((3, 2)), default_camera())


def test_vertex_normals_of_sphere_point_outward():
    s = sphere()
    n = vertex_normals_fast(s.vertices, s.triangles)
    out = s.vertices - [0, -2, -7]
    cos = (n * out).sum(1) / np.linalg.norm(out, axis=1)
    assert np.median(cos) > 0.999


def _warp_errors(a, b, flow, occ):
    """Mean abs error of frame t rebuilt from t+1 with the flow, and with the flow shifted
    by half a pixel (what an almost-right flow scores), on eroded non-occluded face pixels."""
    import cv2
    m = cv2.erode((a.mask & ~occ).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    fa = a.image.astype(np.float32)
    fb = b.image.astype(np.float32)
    err = np.abs(warp_backward(fb, flow) - fa)[m].mean()
    off = np.abs(warp_backward(fb, flow + np.float32([0.5, 0.0])) - fa)[m].mean()
    return err, off, m


@pytest.mark.parametrize("kind", ["orthographic", "perspective"])
def test_flow_warp_reproduces_previous_frame(kind):
    s = sphere()
    cam = default_camera(128, 128, kind=kind, distance=50)
    # uniform lighting: brightness constancy holds under rotation, so warping must match
    from synth.render.shading import Light
    r = Renderer(s, texture=noise_texture(), camera=cam, supersample=2,
                 light=Light(ambient=1.0, specular_scale=0.0))
    a = r.render(s.vertices, pose=HeadPose(yaw=3, pitch=1, translation=(0.1, 0, 0)))
    b = r.render(s.vertices, pose=HeadPose(yaw=6, pitch=2, roll=2, translation=(0.2, 0.1, 0)))
    flow, occ, dis = flow_and_occlusion(r, a, b)
    err, off, m = _warp_errors(a, b, flow, occ)
    assert err < 1.0 and err < off / 2.5
    assert np.abs(flow[m]).max() > 1.0
    assert occ[a.mask].sum() > 0      # the limb rotates out of view
    assert dis[b.mask].sum() > 0      # and in on the other side


def test_flow_warp_under_translation_with_shading():
    s = sphere()
    r = Renderer(s, texture=noise_texture(), camera=default_camera(128, 128), supersample=2)
    a = r.render(s.vertices)
    b = r.render(s.vertices, pose=HeadPose(translation=(0.25, -0.15, 0)))
    flow, occ, _ = flow_and_occlusion(r, a, b)
    err, off, _ = _warp_errors(a, b, flow, occ)
    assert err < 1.0 and err < off / 2.5


def test_zero_motion_zero_flow():
    s = sphere()
    r = Renderer(s, camera=default_camera(96, 96))
    a = r.render(s.vertices, shade=False)
    flow, occ = forward_flow(r, a, a)
    assert np.abs(flow).max() < 1e-9
    assert not occ.any()


def test_plane_translation_flow_is_exact():
    s = plane(n=10, size=12.0)
    cam = default_camera(80, 80)
    r = Renderer(s, camera=cam)
    a = r.render(s.vertices, shade=False)
    b = r.render(s.vertices + [0.3, -0.2, 0.0], shade=False)
    flow, occ = forward_flow(r, a, b)
    m = a.mask & ~occ
    np.testing.assert_allclose(flow[m, 0], 0.3 * cam.scale, atol=1e-4)
    np.testing.assert_allclose(flow[m, 1], 0.2 * cam.scale, atol=1e-4)
    # pixels leaving the image are flagged
    c = r.render(s.vertices + [3.0, 0, 0], shade=False)
    _, occ2 = forward_flow(r, a, c)
    assert occ2[:, -5:][a.mask[:, -5:]].all()


def test_occlusion_by_a_nearer_surface():
    back = plane(n=8, size=12.0, z=-1.0)
    front = plane(n=4, size=4.0, z=1.0, centre=(-4.0, -2.0))
    from synth.render.renderer import Surface
    V = np.concatenate([back.vertices, front.vertices])
    T = np.concatenate([back.triangles, front.triangles + len(back.vertices)])
    surf = Surface(vertices=V, triangles=T, uv=np.zeros((len(V), 2)))
    r = Renderer(surf, camera=default_camera(96, 96))
    a = r.render(V, shade=False)
    V2 = V.copy()
    V2[len(back.vertices):, 0] += 6.0        # the small front square slides right
    b = r.render(V2, shade=False)
    flow, occ, dis = flow_and_occlusion(r, a, b)
    # back-plane pixels now under the front square are occluded
    under = (b.triangle_id >= len(back.triangles)) & (a.triangle_id < len(back.triangles)) \
        & (a.triangle_id >= 0)
    assert occ[under].mean() > 0.95
    # back-plane pixels where the square was are disoccluded in frame t+1
    uncovered = (a.triangle_id >= len(back.triangles)) & (b.triangle_id < len(back.triangles))
    uncovered &= b.triangle_id >= 0
    assert dis[uncovered].mean() > 0.95
    visible = b.mask & ~uncovered & (b.triangle_id < len(back.triangles))
    assert dis[visible].mean() < 0.02


def test_supersampling_and_grey_output():
    s = sphere()
    r1 = Renderer(s, texture=noise_texture(), camera=default_camera(64, 48), grey=True,
                  supersample=3)
    res = r1.render(s.vertices)
    assert res.image.shape == (48, 64) and res.image.dtype == np.uint8
    assert res.triangle_id.shape == (48, 64)
    with pytest.raises(ValueError, match="supersample"):
        Renderer(s, supersample=0)
    with pytest.raises(ValueError, match="vertices"):
        r1.render(s.vertices[:-1])


def test_lighting_brightens_lit_side():
    s = sphere()
    from synth.render.shading import Light
    r = Renderer(s, camera=default_camera(96, 96), light=Light(direction=(1, 0, 0.2),
                                                               ambient=0.2))
    img = r.render(s.vertices).image.astype(float).mean(2)
    row = img[48]
    assert row[70] > row[26] + 40
