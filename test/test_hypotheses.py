"""Object- and trajectory-level hypotheses and their residual blocks (moseg_ros.core.hypotheses)."""

import cv2
import numpy as np
import pytest

from moseg_ros.core import flow_model, hypotheses

K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])


def _tracks(rng: np.random.Generator, n_static: int, n_moving: int, n_frames: int = 6) -> tuple[np.ndarray, ...]:
    """Static points seen by a forward-moving camera, plus a rigid object with its own rotation/translation."""
    static = rng.uniform([-6, -3, 8], [6, 3, 25], (n_static, 3))
    moving = rng.uniform([-1, -1, 10], [1, 1, 12], (n_moving, 3))
    xy = np.zeros((n_static + n_moving, n_frames, 2))
    for f in range(n_frames):
        cam = np.array([0.0, 0.0, -0.5 * f])
        R, _ = cv2.Rodrigues(np.array([0.0, 0.04 * f, 0.0]))
        obj = (moving - moving.mean(0)) @ R.T + moving.mean(0) + np.array([0.4 * f, 0.0, 0.0])
        pts = np.concatenate([static, obj]) - cam
        p = pts @ K.T
        xy[:, f] = p[:, :2] / p[:, 2:]
    labels = np.repeat([0, 1], [n_static, n_moving])
    return xy, np.ones(xy.shape[:2], dtype=bool), labels


def test_trajectory_hypotheses_blocks_cover_visible_items():
    rng = np.random.default_rng(0)
    xy, visible, labels = _tracks(rng, 60, 30)
    visible[:10, 4:] = False  # ten tracks end early
    blocks = hypotheses.trajectory_hypotheses(xy, visible, "fundamental", gap=2, n_hypotheses=200, rng=rng)
    assert len(blocks) == 4  # pairs (0, 2) .. (3, 5)
    assert [len(b.items) for b in blocks] == [90, 90, 80, 80]
    assert all(b.residuals.shape == (len(b.items), 200) for b in blocks)
    # Some hypotheses come from pure static samples: their residual on every static point is ~0.
    r = blocks[0].residuals
    pure = np.all(r[labels[blocks[0].items] == 0] < 1e-9, axis=0)
    assert pure.any() and np.all(r[labels[blocks[0].items] == 1][:, pure].mean(axis=0) > 1e-3)


def _pure_share(blocks: list, labels: np.ndarray) -> float:
    """Share of hypotheses that fit every point of one motion exactly (fitted to a sample of that motion)."""
    pure = []
    for b in blocks:
        lab = labels[b.items]
        pure.append(np.any([np.all(b.residuals[lab == k] < 1e-9, axis=0) for k in (0, 1)], axis=0))
    return float(np.concatenate(pure).mean())


def test_guided_hypotheses_are_drawn_inside_the_groups():
    # A small object (10 of 100 points): random 8-point samples are seldom pure, guided ones always are.
    rng = np.random.default_rng(3)
    xy, visible, labels = _tracks(rng, 90, 10)
    random = hypotheses.trajectory_hypotheses(xy, visible, "fundamental", gap=2, n_hypotheses=300, rng=rng)
    guided = hypotheses.trajectory_hypotheses(xy, visible, "fundamental", gap=2, n_hypotheses=300, rng=rng,
                                              groups=labels, guided_fraction=1.0)
    assert _pure_share(random, labels) < 0.6 and _pure_share(guided, labels) == 1.0
    half = hypotheses.trajectory_hypotheses(xy, visible, "fundamental", gap=2, n_hypotheses=300, rng=rng,
                                            groups=labels, guided_fraction=0.5)
    assert _pure_share(random, labels) < _pure_share(half, labels) < 1.0
    with pytest.raises(ValueError, match="guided_fraction"):
        hypotheses.trajectory_hypotheses(xy, visible, "fundamental", gap=2, n_hypotheses=10, rng=rng,
                                         guided_fraction=0.5)


@pytest.mark.parametrize("model", ["homography", "affine"])
def test_other_models_give_blocks(model):
    rng = np.random.default_rng(1)
    xy, visible, _ = _tracks(rng, 40, 20)
    blocks = hypotheses.trajectory_hypotheses(xy, visible, model, gap=1, n_hypotheses=20, rng=rng)
    assert len(blocks) == 5 and all(b.residuals.shape == (60, 20) for b in blocks)
    assert all(np.all(np.isfinite(b.residuals)) for b in blocks)


def test_minimal_samples_have_distinct_points():
    rng = np.random.default_rng(2)
    for n in (10, 500):
        s = hypotheses.sample_minimal_sets(n, 8, 300, rng)
        assert s.shape == (300, 8) and s.max() < n
        assert np.all(np.diff(np.sort(s, axis=1), axis=1) > 0)


def test_object_epipolar_residuals_separate_motions_and_keep_small_objects():
    rng = np.random.default_rng(3)
    xy, visible, labels = _tracks(rng, 80, 30)
    owner = labels.copy()
    owner[-5:] = 2  # five of the moving trajectories form a third, small object
    blocks = hypotheses.object_epipolar_residuals(xy, visible, owner, 3, gap=2)
    assert len(blocks) == 4
    for b in blocks:
        assert b.items.tolist() == [0, 1, 2]
        assert b.owners.tolist() == [0, 1]  # object 2 has < 8 trajectories: no model, still residuals
        r = b.residuals
        assert r[0, 0] < 1e-9 and r[1, 1] < 1e-9  # own models are exact
        assert r[1, 0] > 1.0 and r[0, 1] > 1.0  # the other motion's model does not fit
        assert r[2, 1] < 1e-9 and r[2, 0] > 1.0  # the small object moves with object 1


def test_object_flow_residuals_from_label_maps():
    rng = np.random.default_rng(4)
    n_frames, height, width = 3, 60, 80
    labels = np.zeros((n_frames, height, width), dtype=np.int32)
    labels[:, 10:40, 10:40] = 7
    labels[:, 45:50, 70:72] = 9  # 10 pixels: no model of its own at grid step 1 with 24 vectors needed
    ys, xs = np.mgrid[0:height, 0:width]
    xy = np.stack([xs.ravel(), ys.ravel()], 1).astype(float)
    truth = rng.normal(size=(2, 12)) * np.array([1.0, 1e-2, 1e-2, 1e-4, 1e-4, 1e-4] * 2)
    field = flow_model.predict_flow(truth, xy, (width, height)).reshape(2, height, width, 2)
    flows = np.where((labels[:-1] == 7)[..., None], field[1], field[0]).astype(np.float32)
    blocks = hypotheses.object_flow_residuals(labels, flows, np.array([0, 7, 9]), grid_step=1)
    assert len(blocks) == 2
    for b in blocks:
        assert b.items.tolist() == [0, 1, 2] and b.owners.tolist() == [0, 1]
        assert b.residuals[0, 0] < 1e-8 and b.residuals[1, 1] < 1e-8 and b.residuals[2, 0] < 1e-8
        assert b.residuals[0, 1] > 1e-3 and b.residuals[1, 0] > 1e-3


def test_thinning_keeps_every_sth_member_of_large_groups_only():
    groups = np.array([0, 1, 0, -1, 0, 0, 1, 0, 2])  # group 0: five members, 1: two, 2: one
    thinned = hypotheses.thinned_groups(groups, 3, max_members=2)
    # Group 0 keeps its 1st and 4th members (every ceil(5 / 2) = 3rd); groups 1 and 2 stay whole.
    assert thinned.tolist() == [0, 1, -1, -1, -1, 0, 1, -1, 2]
    assert hypotheses.thinned_groups(groups, 3, max_members=5).tolist() == groups.tolist()


def test_thinned_flow_vectors_give_the_same_models():
    rng = np.random.default_rng(5)
    n_frames, height, width = 3, 60, 80
    labels = np.zeros((n_frames, height, width), dtype=np.int32)
    labels[:, 10:40, 10:40] = 7
    ys, xs = np.mgrid[0:height, 0:width]
    xy = np.stack([xs.ravel(), ys.ravel()], 1).astype(float)
    truth = rng.normal(size=(2, 12)) * np.array([1.0, 1e-2, 1e-2, 1e-4, 1e-4, 1e-4] * 2)
    field = flow_model.predict_flow(truth, xy, (width, height)).reshape(2, height, width, 2)
    flows = np.where((labels[:-1] == 7)[..., None], field[1], field[0]).astype(np.float32)
    flows += rng.normal(scale=0.1, size=flows.shape).astype(np.float32)
    full = hypotheses.object_flow_residuals(labels, flows, np.array([0, 7]), grid_step=1)
    thin = hypotheses.object_flow_residuals(labels, flows, np.array([0, 7]), grid_step=1, max_vectors=300)
    for a, b in zip(full, thin):
        # 3900 background and 900 object vectors against 300 of each: each object's own model fits it as well,
        # and the other's as badly (a model extrapolated over a region errs unevenly: a sample's mean varies more).
        np.testing.assert_allclose(np.diag(b.residuals), np.diag(a.residuals), rtol=0.15)
        np.testing.assert_allclose(b.residuals, a.residuals, rtol=0.25)
        np.testing.assert_allclose(b.energy, a.energy, rtol=0.1)


def test_bad_input_raises():
    with pytest.raises(ValueError, match="unknown model"):
        hypotheses.trajectory_hypotheses(np.zeros((10, 3, 2)), np.ones((10, 3), bool), "conic", gap=1,
                                         n_hypotheses=5, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="tracks_visible"):
        hypotheses.object_epipolar_residuals(np.zeros((10, 3, 2)), np.ones((10, 2), bool), np.zeros(10, int), 1,
                                             gap=1)
    with pytest.raises(ValueError, match="frame gap"):
        hypotheses.frame_pairs(5, 0)


def test_members_are_fitted_as_with_zero_weights_on_everything_else():
    # The bucketed fit of the object-level models equals the eight-point fit over all points with the
    # non-members weighted 0 (up to the sign of F).
    from moseg_ros.core import geometry

    rng = np.random.default_rng(4)
    xy, visible, labels = _tracks(rng, 200, 30)
    x1, x2 = xy[None, :, 0], xy[None, :, 2]
    member = np.stack([labels == 0, labels == 1, np.arange(230) < 5])  # the last set is too small
    fitted, valid = hypotheses._fit_members(x1, x2, member, 8)
    reference, reference_valid = geometry.fundamental_eight_point(np.repeat(x1, 3, 0), np.repeat(x2, 3, 0),
                                                                  member.astype(float))
    assert valid.tolist() == [True, True, False] and reference_valid[:2].all()
    for f, ref in zip(fitted[:2], reference[:2]):
        np.testing.assert_allclose(f * np.sign(np.vdot(f, ref)), ref, atol=1e-8)
