"""Bundle adjustment and resection through the Python binding, against known truth."""
import numpy as np
import pytest

from cloudcontrol import CloudControlError
from cloudcontrol.adjust import CHECK, CONTROL, TIE, Block, resect
from cloudcontrol.geometry import Camera, Pose

W, H, F = 4000, 3000, 3500.0


def nadir(c, kappa=0.0):
    return Pose.from_opk(0.0, 0.0, kappa, c)


def make_block(rng, noise=0.5):
    cam = Camera(W, H, F, F, W / 2, H / 2)
    poses = [nadir([x, y, 800.0]) for y in (0.0, 450.0) for x in np.arange(0, 1300, 190.0)]
    n = 2500
    X = np.column_stack([rng.uniform(-200, 1500, n), rng.uniform(-250, 700, n), rng.uniform(-20, 40, n)])
    obs = []
    for j, p in enumerate(poses):
        uv = np.full((n, 2), np.nan)
        xc = (X - p.center) @ p.rotation.T
        ok = xc[:, 2] > 0
        uv[ok] = cam.project(p, X[ok])
        ok &= (uv[:, 0] > 10) & (uv[:, 1] > 10) & (uv[:, 0] < W - 10) & (uv[:, 1] < H - 10)
        for k in np.nonzero(ok)[0]:
            obs.append((k, j, uv[k] + rng.normal(0, noise, 2)))
    return cam, poses, X, obs


def test_block_adjustment_recovers_truth_and_sigma0():
    rng = np.random.default_rng(4)
    cam, poses, X, obs = make_block(rng)
    counts = np.bincount([o[0] for o in obs], minlength=len(X))
    b = Block()
    b.add_camera(1, cam)
    for j, p in enumerate(poses):
        start = Pose(p.rotation, p.center + rng.normal(0, 2.0, 3))
        b.add_photo(j + 1, 1, start)
    used = np.nonzero(counts >= 2)[0]
    kinds = np.full(len(used), TIE)
    kinds[:12] = CONTROL
    kinds[12:18] = CHECK
    xyz = X[used] + np.where(kinds[:, None] == TIE, rng.normal(0, 1.0, (len(used), 3)), 0.0)
    b.add_points(used + 1, kinds, xyz, np.full((len(used), 3), 0.02))
    sel = [o for o in obs if counts[o[0]] >= 2]
    b.add_observations([o[0] + 1 for o in sel], [o[1] + 1 for o in sel], np.array([o[2] for o in sel]), 1.0)
    s = b.adjust()
    assert s["converged"] == 1
    assert abs(s["sigma0"] / 0.5 - 1.0) < 0.1, s
    for j, p in enumerate(poses):
        q, sig = b.photo(j + 1)
        err = np.linalg.norm(q.center - p.center)
        assert err < 6 * np.linalg.norm(sig[3:]) + 0.01, (j, err, sig)
    rep = b.report()
    assert rep["check"]["count"] == 6 and rep["check"]["rmse_plan_m"] < 0.2
    assert len(rep["photo_precision"]) == len(poses)


def test_resection_with_outliers_and_bad_input():
    rng = np.random.default_rng(9)
    cam = Camera(W, H, F, F, W / 2, H / 2)
    truth = Pose.from_opk(0.02, -0.01, 0.4, [100.0, 50.0, 900.0])
    X = np.column_stack([rng.uniform(-200, 400, 20), rng.uniform(-150, 250, 20), rng.uniform(0, 50, 20)])
    uv = cam.project(truth, X) + rng.normal(0, 0.3, (20, 2))
    uv[:8] += rng.uniform(30, 100, (8, 2))
    pose, inl, cov = resect(cam, uv, X, sigma_px=0.3)
    assert np.linalg.norm(pose.center - truth.center) < 1.0
    assert not inl[:8].any() and inl[8:].all()
    assert np.all(np.diag(cov) > 0)
    bad = uv.copy()
    bad[3, 0] = np.nan
    with pytest.raises(CloudControlError, match="pixels"):
        resect(cam, bad, X)
    with pytest.raises(CloudControlError, match="at least 3"):
        resect(cam, uv[:2], X[:2])


def test_unknown_ids_are_named():
    b = Block()
    cam = Camera(W, H, F, F, W / 2, H / 2)
    with pytest.raises(CloudControlError, match="unknown camera 7"):
        b.add_photo(1, 7, nadir([0, 0, 800.0]))
    b.add_camera(1, cam)
    b.add_photo(1, 1, nadir([0, 0, 800.0]))
    b.add_points([5], [TIE], [[0, 0, 0]])
    with pytest.raises(CloudControlError, match="unknown point 6"):
        b.add_observations([6], [1], [[10.0, 10.0]], 1.0)
    with pytest.raises(CloudControlError, match="two"):
        b.adjust()


def test_pos_priors_and_lidar_planes_through_the_abi():
    rng = np.random.default_rng(5)
    cam, poses, X, obs = make_block(rng)
    counts = np.bincount([o[0] for o in obs], minlength=len(X))
    used = np.nonzero(counts >= 2)[0]
    b = Block()
    b.add_camera(1, cam)
    for j, p in enumerate(poses):
        b.add_photo(j + 1, 1, Pose(p.rotation, p.center + rng.normal(0, 2.0, 3)))
        b.set_pos_prior(j + 1, p.center + rng.normal(0, 0.05, 3), [0.05] * 3, p.rotation, 1e-3)
    b.add_points(used + 1, np.full(len(used), TIE), X[used] + rng.normal(0, 1.0, (len(used), 3)))
    sel = [o for o in obs if counts[o[0]] >= 2]
    b.add_observations([o[0] + 1 for o in sel], [o[1] + 1 for o in sel], np.array([o[2] for o in sel]), 1.0)
    # Horizontal LiDAR planes through every tenth tie point's true height.
    pl = used[::10]
    b.add_planes(pl + 1, np.tile([0.0, 0.0, 1.0], (len(pl), 1)), X[pl, 2], np.full(len(pl), 1 / 0.05**2))
    s = b.adjust()
    rep = b.report()
    assert rep["datum"] == "pos+lidar_planes"
    assert abs(s["sigma0"] / 0.5 - 1.0) < 0.1
    for j, p in enumerate(poses):
        q, _ = b.photo(j + 1)
        assert np.linalg.norm(q.center - p.center) < 0.2
    assert abs(b.point(int(pl[0]) + 1)[2] - X[pl[0], 2]) < 0.2


def test_a_lidar_datum_error_is_estimated_through_the_abi():
    """Planes 0.3 m above the true surface: held as the datum they lift the ground with
    them; with the LiDAR datum σ set the shift is estimated (its σ, about 5 cm here, is
    the block's vertical scale as 14 POS centres of 5 cm fix it, over six draws the
    estimates scatter by as much) and the ground is lifted only by what the shift
    leaves."""
    rng = np.random.default_rng(8)
    cam, poses, X, obs = make_block(rng)
    counts = np.bincount([o[0] for o in obs], minlength=len(X))
    used = np.nonzero(counts >= 2)[0]
    sel = [o for o in obs if counts[o[0]] >= 2]
    pl = used[::10]
    start = X[used] + rng.normal(0, 1.0, (len(used), 3))
    pos = [(p.center + rng.normal(0, 2.0, 3), p.center + rng.normal(0, 0.05, 3)) for p in poses]

    def run(sigma):
        b = Block()
        b.add_camera(1, cam)
        for j, p in enumerate(poses):
            b.add_photo(j + 1, 1, Pose(p.rotation, pos[j][0]))
            b.set_pos_prior(j + 1, pos[j][1], [0.05] * 3, p.rotation, 1e-3)
        b.add_points(used + 1, np.full(len(used), TIE), start)
        b.add_observations([o[0] + 1 for o in sel], [o[1] + 1 for o in sel], np.array([o[2] for o in sel]), 1.0)
        b.add_planes(pl + 1, np.tile([0.0, 0.0, 1.0], (len(pl), 1)), X[pl, 2] + 0.3, np.full(len(pl), 1 / 0.05**2))
        if sigma is not None:
            b.set_lidar_datum_sigma(sigma)
        b.adjust()
        dz = np.mean([b.point(int(i) + 1)[2] - X[i, 2] for i in used])
        return dz, b.report().get("lidar_datum")

    held, none = run(None)
    free, rep = run(0.5)
    assert none is None
    assert held > 0.2, held
    shift, sigma = rep["shift_m"][2], rep["sigma_m"][2]
    assert abs(shift - 0.3) < 4 * sigma and sigma < 0.1, rep
    assert abs(free - (0.3 - shift)) < 0.02, (free, rep)
    assert abs(free) < held
    assert rep["prior_sigma_m"] == [0.5, 0.5, 0.5]
    b = Block()
    with pytest.raises(CloudControlError, match="sigma_m"):
        b.set_lidar_datum_sigma(float("nan"))
