"""Camera projection over the C ABI against hand-computed values and numpy."""
import math

import numpy as np
import pytest

import cloudcontrol as cc


def brown_project(points, center, f, cx, cy, k1, k2, k3, p1, p2):
    """Independent numpy implementation of a nadir (OPK = 0) Brown projection."""
    # OPK = 0: camera x = world x, camera y = -world y, camera z = -world z.
    d = points - center
    xc, yc, zc = d[:, 0], -d[:, 1], -d[:, 2]
    x, y = xc / zc, yc / zc
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.column_stack([f * xd + cx, f * yd + cy])


def test_version():
    assert cc.version() == "0.1.0"


def test_projection_matches_numpy_and_back_projection_inverts():
    cam = cc.Camera(6000, 4000, 8000.0, 8000.0, 3000.5, 2000.5, k1=-0.1, k2=0.02, k3=0.0, p1=1e-4, p2=-2e-4)
    center = np.array([10.0, -20.0, 1500.0])
    pose = cc.Pose.from_opk(0.0, 0.0, 0.0, center)
    np.testing.assert_allclose(pose.rotation, np.diag([1.0, -1.0, -1.0]), atol=1e-15)
    rng = np.random.default_rng(5)
    pts = np.column_stack([rng.uniform(-200, 200, 500), rng.uniform(-150, 150, 500), rng.uniform(0, 50, 500)])
    px = cam.project(pose, pts)
    expected = brown_project(pts, center, 8000.0, 3000.5, 2000.5, -0.1, 0.02, 0.0, 1e-4, -2e-4)
    np.testing.assert_allclose(px, expected, atol=1e-8)
    dirs = cam.back_project(pose, px)
    t = (pts[:, 2] - center[2]) / dirs[:, 2]
    np.testing.assert_allclose(center + dirs * t[:, None], pts, atol=1e-6)


def test_rotated_pose_round_trip():
    cam = cc.Camera(1000, 1000, 1200.0, 1200.0, 500.0, 500.0)
    pose = cc.Pose.from_opk(0.05, -0.03, math.radians(30), [0, 0, 800])
    r = pose.rotation
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-14)
    px = cam.project(pose, [[12.0, 7.0, 3.0]])
    d = cam.back_project(pose, px)[0]
    t = (3.0 - 800.0) / d[2]
    np.testing.assert_allclose(np.array([0, 0, 800.0]) + t * d, [12.0, 7.0, 3.0], atol=1e-9)


def test_errors_carry_the_library_message():
    with pytest.raises(cc.CloudControlError, match="focal length"):
        cc.Camera(100, 100, -5.0, 100.0, 50.0, 50.0)
    cam = cc.Camera(100, 100, 100.0, 100.0, 50.0, 50.0)
    pose = cc.Pose.from_opk(0, 0, 0, [0, 0, 100])
    with pytest.raises(cc.CloudControlError, match=r"points\[1\]\.x is not finite") as e:
        cam.project(pose, [[0, 0, 0], [np.nan, 0, 0]])
    assert e.value.status_name == "NOT_FINITE"
    with pytest.raises(cc.CloudControlError, match="behind the camera"):
        cam.project(pose, [[0, 0, 500]])
    with pytest.raises(cc.CloudControlError, match="zero"):
        cam.project(pose, np.zeros((0, 3)))
    with pytest.raises(cc.CloudControlError, match="not a proper rotation"):
        cam.project(cc.Pose(np.diag([1.0, 1.0, 2.0]), [0, 0, 100]), [[0, 0, 0]])
    with pytest.raises(ValueError):
        cam.project(pose, [[1.0, 2.0]])
