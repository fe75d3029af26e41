"""Handles through the C ABI from Python: a double free, a freed handle and a handle of the
wrong type give CCP_STATUS_INVALID_HANDLE (10) and a message, not a crash; one block adjusted
from 8 threads at once (ctypes releases the GIL) ends as 8 adjustments in a row end."""
import ctypes
import threading

import numpy as np

from cloudcontrol._ffi import last_error, lib
from cloudcontrol.adjust import CONTROL, TIE, AdjustOptions, AdjustSummary, Block, _BlockP
from cloudcontrol.geometry import Camera, CcpPose, Pose, _CameraP

INVALID_HANDLE = 10
W, H, F = 4000, 3000, 3500.0


def test_double_free_and_use_after_free_are_refused():
    params = (ctypes.c_double * 4)(F, F, W / 2, H / 2)
    h = _CameraP()
    assert lib.ccp_camera_new_frame(W, H, params, 4, ctypes.byref(h)) == 0
    assert lib.ccp_camera_free(h) == 0
    assert lib.ccp_camera_free(h) == INVALID_HANDLE
    assert "freed twice" in last_error()
    pose = Pose.from_opk(0, 0, 0, [0, 0, 800])._c()
    x = (ctypes.c_double * 3)(0, 0, 0)
    uv = (ctypes.c_double * 2)()
    assert lib.ccp_project(h, ctypes.byref(pose), x, 1, uv, 2) == INVALID_HANDLE
    assert "CcpCamera handle that was freed" in last_error()
    assert lib.ccp_camera_free(None) == 0


def test_a_handle_of_the_wrong_type_is_refused_and_left_intact():
    cam = Camera(W, H, F, F, W / 2, H / 2)
    as_block = ctypes.cast(cam._h, _BlockP)
    pose = Pose.from_opk(0, 0, 0, [0, 0, 800])._c()
    assert lib.ccp_block_add_photo(as_block, 1, 1, ctypes.byref(pose)) == INVALID_HANDLE
    assert "is a CcpCamera handle, not a CcpBlock" in last_error()
    assert lib.ccp_block_free(as_block) == INVALID_HANDLE
    # The camera is still alive and right.
    uv = cam.project(Pose.from_opk(0, 0, 0, [0, 0, 800]), [[0.0, 0.0, 0.0]])
    assert np.allclose(uv, [[W / 2, H / 2]])
    b = Block()
    as_camera = ctypes.cast(b._h, _CameraP)
    assert lib.ccp_camera_free(as_camera) == INVALID_HANDLE
    assert "is a CcpBlock handle, not a CcpCamera" in last_error()


def make_block(seed=4):
    rng = np.random.default_rng(seed)
    cam = Camera(W, H, F, F, W / 2, H / 2)
    poses = [Pose.from_opk(0, 0, 0, [x, y, 800.0]) for y in (0.0, 450.0) for x in np.arange(0, 1300, 190.0)]
    n = 600
    X = np.column_stack([rng.uniform(-50, 1350, n), rng.uniform(-175, 625, n), rng.uniform(-10, 30, n)])
    b = Block()
    b.add_camera(1, cam)
    for j, p in enumerate(poses):
        b.add_photo(j + 1, 1, Pose(p.rotation, p.center + rng.normal(0, 2.0, 3)))
    kinds = np.full(n, TIE)
    kinds[:12] = CONTROL
    b.add_points(np.arange(1, n + 1), kinds, X, np.full((n, 3), 0.02))
    pid, phid, px = [], [], []
    for j, p in enumerate(poses):
        uv = cam.project(p, X)
        ok = (uv[:, 0] > 10) & (uv[:, 1] > 10) & (uv[:, 0] < W - 10) & (uv[:, 1] < H - 10)
        for k in np.nonzero(ok)[0]:
            pid.append(k + 1)
            phid.append(j + 1)
            px.append(uv[k] + rng.normal(0, 0.5, 2))
    b.add_observations(pid, phid, np.array(px), 1.0)
    return b, cam, len(poses)


def plain_adjust(h):
    """One least-squares adjustment without loss or rejection, by the raw C call."""
    o = AdjustOptions(0, 1.0, 0, 3.0, 50, 1)
    s = AdjustSummary()
    st = lib.ccp_block_adjust(h, ctypes.byref(o), ctypes.byref(s))
    return st, s.as_dict()


def centres(b, n):
    return np.array([b.photo(j + 1)[0].center for j in range(n)])


def test_eight_threads_adjusting_one_block_match_eight_adjustments_in_a_row():
    ref, _, n = make_block()
    st, first = plain_adjust(ref._h)
    assert st == 0 and first["converged"] == 1
    assert abs(first["sigma0"] / 0.5 - 1) < 0.1, first
    for _ in range(7):
        assert plain_adjust(ref._h)[0] == 0
    want = centres(ref, n)

    shared, _, _ = make_block()
    results = [None] * 8

    def work(i):
        results[i] = plain_adjust(shared._h)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for st, s in results:
        assert st == 0, last_error()
        assert s["converged"] == 1
        assert abs(s["sigma0"] - first["sigma0"]) < 1e-6 * first["sigma0"], (s, first)
    assert np.allclose(centres(shared, n), want, rtol=0, atol=1e-9)
