"""The pinhole camera: its frame, its rasteriser pose and its primary rays agree."""

from __future__ import annotations

import numpy as np

from jkatana.render.camera import Camera


def test_pose_is_the_frame_and_rays_leave_along_forward():
    cam = Camera.orbit((0.1, 0.2, -0.3), 2.5, azimuth_deg=40.0, elevation_deg=25.0, fov_deg=30.0, width=9, height=7)
    right, up, fwd = cam.frame()
    pose = cam.pose()
    np.testing.assert_allclose(pose[:3, :3].T @ pose[:3, :3], np.eye(3), atol=1e-12)  # orthonormal
    assert np.linalg.det(pose[:3, :3]) > 0  # right-handed
    np.testing.assert_allclose(pose[:3, 2], -fwd, atol=1e-15)  # looks along its −Z (OpenGL)
    np.testing.assert_allclose(pose[:3, 3], cam.position, atol=1e-15)
    np.testing.assert_allclose(pose[3], [0, 0, 0, 1])
    origin, d = cam.rays()
    np.testing.assert_allclose(origin, cam.position)
    centre = d[3, 4]  # odd sizes: the middle pixel's ray is the optical axis
    np.testing.assert_allclose(centre, fwd, atol=1e-12)
    assert d[0, 4] @ up > 0 and d[3, 8] @ right > 0  # row 0 is the top, the last column the right
