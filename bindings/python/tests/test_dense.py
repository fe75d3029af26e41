"""Dense matching from Python: one stereo pair through ``ccp_match_pair`` against a surface
rendered in numpy (its heights are the truth), and a bad pair refused naming the input."""
import numpy as np
import pytest

import cloudcontrol
from cloudcontrol import Camera, Pose

F, W, H, FLY = 1000.0, 640, 480, 100.0  # focal (px), photo size, flying height (m)


def height(x, y):
    """The true surface: a gentle hill and a slope (m)."""
    return 3.0 * np.sin(x / 17.0) * np.cos(y / 23.0) + 0.04 * x


def texture(x, y):
    rng = np.random.default_rng(5)
    v = np.zeros_like(x)
    for _ in range(24):
        k = rng.uniform(0.4, 3.0, 2)
        v += np.sin(k[0] * x + k[1] * y + rng.uniform(0, 6.3))
    return 128.0 + 14.0 * v


def render(pose):
    """Grey image of the surface seen by a nadir pinhole camera (ray marched to the surface
    by fixed-point iteration, which converges for gentle slopes)."""
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    d = np.stack([(u - W / 2) / F, (v - H / 2) / F, np.ones_like(u)], -1) @ pose.rotation
    c = pose.center
    t = (c[2] - 0.0) / -d[..., 2]
    for _ in range(30):
        x, y = c[0] + t * d[..., 0], c[1] + t * d[..., 1]
        t = (c[2] - height(x, y)) / -d[..., 2]
    x, y = c[0] + t * d[..., 0], c[1] + t * d[..., 1]
    # Each pixel integrates its footprint: 3 x 3 samples of the texture.
    g = F / FLY
    acc = sum(texture(x + a / (3 * g), y + b / (3 * g)) for a in (-1, 0, 1) for b in (-1, 0, 1)) / 9
    return acc + np.random.default_rng(int(c[0] * 10)).normal(0, 1.0, acc.shape)


def test_a_rendered_pair_gives_the_surface_heights():
    cam = Camera(W, H, F, F, W / 2, H / 2)
    # Nadir, image x east, image y south: world->camera rotation diag(1, -1, -1).
    rot = np.diag([1.0, -1.0, -1.0])
    left, right = Pose(rot, [0.0, 0.0, FLY]), Pose(rot, [30.0, 0.0, FLY])
    pts = cloudcontrol.match_pair((cam, left, render(left)), (cam, right, render(right)),
                                  (-15.0, 15.0))
    assert pts.shape[1] == 3
    gsd = FLY / F
    # Most of the overlap (about 29 000 left pixels see both photos) is matched.
    assert len(pts) > 0.8 * (W - 300) * H, len(pts)
    dz = pts[:, 2] - height(pts[:, 0], pts[:, 1])
    med = np.median(dz)
    nmad = 1.4826 * np.median(np.abs(dz - med))
    assert abs(med) <= 0.2 * gsd and nmad <= 1.0 * gsd, (med, nmad)


def test_a_pair_with_one_centre_is_refused_naming_it():
    cam = Camera(W, H, F, F, W / 2, H / 2)
    rot = np.diag([1.0, -1.0, -1.0])
    p = Pose(rot, [0.0, 0.0, FLY])
    img = np.zeros((H, W), np.float32)
    with pytest.raises(cloudcontrol.CloudControlError, match="centres coincide"):
        cloudcontrol.match_pair((cam, p, img), (cam, p, img), (-1.0, 1.0))
    with pytest.raises(cloudcontrol.CloudControlError, match="left"):
        cloudcontrol.match_pair((cam, p, img[:10]), (cam, p, img), (-1.0, 1.0))
