"""Motion hypotheses and the residual of every item under every hypothesis, one block per frame pair.

Two levels share one output form, a list of ``ResidualBlock`` (one per frame pair):

* **trajectory level** (KT3DMoSeg protocol, MVC style; Xu, Cheong, Li, CVPR 2018): each trajectory is an item;
  hypotheses are models (F, H or affine) fitted to random minimal samples of the trajectories visible in both
  frames of the pair; the residual is the model's geometric error on the trajectory's two points.
* **object level** (the paper): each object is an item; the hypotheses are one model per object per frame pair,
  fitted to all of that object's data (eight-point F on its trajectories between frames m and m+gap; the
  quadratic flow model on its flow vectors between m and m+1); the residual of object k under a model is
  k's median Sampson distance (robust to mistracked points), or its mean squared flow error.

Within a block only the items with data in that pair appear; the ordered residual kernel ranks each item's
residuals within a block, so the different scales of different pairs never mix.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from moseg_ros.core import flow_model, geometry


@dataclass(frozen=True)
class ResidualBlock:
    """Residuals of some items under the hypotheses of one frame pair.

    Attributes:
        items: (n,) int indices of the items present in this pair.
        residuals: (n, M) residual of each present item under each hypothesis (NaN = no data; larger = worse).
        owners: (M,) item index each hypothesis was fitted to (object level), or None (random samples).
        energy: (n,) mean squared magnitude of each item's data in the residual's units (flow: mean |uv|²),
            or None; it scales how large a residual an item can have without being an outlier.
    """

    items: np.ndarray
    residuals: np.ndarray
    owners: np.ndarray | None = None
    energy: np.ndarray | None = None


def _check_tracks(tracks_xy: np.ndarray, visible: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    tracks_xy = np.asarray(tracks_xy, dtype=np.float64)
    visible = np.asarray(visible, dtype=bool)
    if tracks_xy.ndim != 3 or tracks_xy.shape[2] != 2:
        raise ValueError(f"tracks_xy must be (N, F, 2), got {tracks_xy.shape}")
    if visible.shape != tracks_xy.shape[:2]:
        raise ValueError(f"tracks_visible must be {tracks_xy.shape[:2]}, got {visible.shape}")
    if not np.all(np.isfinite(tracks_xy[visible])):
        raise ValueError("tracks_xy has non-finite coordinates where tracks_visible is True")
    return tracks_xy, visible


def frame_pairs(n_frames: int, gap: int) -> list[tuple[int, int]]:
    """Pairs (m, m + gap) for every first frame m of a window of n_frames."""
    if gap < 1:
        raise ValueError(f"frame gap must be >= 1, got {gap}")
    return [(m, m + gap) for m in range(n_frames - gap)]


def sample_minimal_sets(n_points: int, sample_size: int, n_samples: int, rng: np.random.Generator) -> np.ndarray:
    """Random samples of distinct points, uniform over subsets.

    Large sets draw with replacement and redraw the few samples that repeat a point (cheaper than a random
    permutation per sample); small sets take the sample_size smallest of random keys.

    Args:
        n_points: points to draw from (at least sample_size).
        sample_size: points per sample.
        n_samples: number of samples.
        rng: random generator.

    Returns:
        (n_samples, sample_size) int indices in [0, n_points), distinct within a row.
    """
    if n_points < sample_size:
        raise ValueError(f"cannot draw samples of {sample_size} distinct points from {n_points}")
    if n_points < 8 * sample_size:
        keys = rng.random((n_samples, n_points))
        return np.argpartition(keys, sample_size - 1, axis=1)[:, :sample_size]
    out = rng.integers(0, n_points, size=(n_samples, sample_size))
    while True:
        srt = np.sort(out, axis=1)
        repeat = np.any(srt[:, 1:] == srt[:, :-1], axis=1)
        if not repeat.any():
            return out
        out[repeat] = rng.integers(0, n_points, size=(int(repeat.sum()), sample_size))


def _guided_samples(present: np.ndarray, groups: np.ndarray, size: int, n_samples: int,
                    rng: np.random.Generator) -> np.ndarray:
    """n_samples minimal samples drawn inside groups (equally many per group with at least 2 × size present
    members), as indices into the trajectories; (0, size) when no group is large enough."""
    members = [present[groups[present] == g] for g in np.unique(groups[present])]
    members = [m for m in members if len(m) >= 2 * size]
    if not members or n_samples <= 0:
        return np.zeros((0, size), dtype=np.int64)
    per_group = -(-n_samples // len(members))
    drawn = [m[sample_minimal_sets(len(m), size, per_group, rng)] for m in members]
    return np.concatenate(drawn)[rng.permutation(per_group * len(members))[:n_samples]]


def trajectory_hypotheses(tracks_xy: np.ndarray, visible: np.ndarray, model: str, *, gap: int,
                          n_hypotheses: int, rng: np.random.Generator, oversample: float = 1.2,
                          groups: np.ndarray | None = None, guided_fraction: float = 0.0) -> list[ResidualBlock]:
    """Random minimal-sample hypotheses of one model type for every frame pair (MVC style).

    For each pair (m, m + gap), the trajectories visible in both frames are the data; ``n_hypotheses`` models
    are fitted to random minimal samples (8 points for F, 4 for H, 3 for affine); degenerate samples are
    dropped (``oversample`` × as many are drawn). Pairs with fewer than twice a minimal sample of visible
    trajectories are skipped. All pairs' samples are fitted in one batched call.

    Args:
        tracks_xy: (N, F, 2) trajectory positions (pixels).
        visible: (N, F) bool visibility.
        model: "fundamental", "homography" or "affine".
        gap: frame gap of a pair.
        n_hypotheses: hypotheses per pair.
        rng: random generator.
        oversample: draw this many times n_hypotheses samples, to make up for degenerate ones.
        groups: optional (N,) int group of each trajectory (a first clustering), for guided samples.
        guided_fraction: share in [0, 1] of the samples drawn inside one group (needs ``groups``).

    Returns:
        One ResidualBlock per usable pair: items (n,), residuals (n, <= n_hypotheses) (Sampson distance for F,
        symmetric transfer error for H, transfer error for affine).
    """
    tracks_xy, visible = _check_tracks(tracks_xy, visible)
    if model not in geometry.MINIMAL_SAMPLE:
        raise ValueError(f"unknown model {model!r}; expected one of {sorted(geometry.MINIMAL_SAMPLE)}")
    if n_hypotheses < 1:
        raise ValueError(f"n_hypotheses must be >= 1, got {n_hypotheses}")
    size = geometry.MINIMAL_SAMPLE[model]
    n_draw = int(np.ceil(oversample * n_hypotheses))
    if not 0.0 <= guided_fraction <= 1.0 or (guided_fraction > 0 and groups is None):
        raise ValueError(f"guided_fraction must be in [0, 1] and needs groups, got {guided_fraction}")
    n_guided = int(round(guided_fraction * n_draw))
    pairs, items, samples = [], [], []
    for m0, m1 in frame_pairs(tracks_xy.shape[1], gap):
        present = np.flatnonzero(visible[:, m0] & visible[:, m1])
        if len(present) < 2 * size:
            continue
        pairs.append((m0, m1))
        items.append(present)
        guided = _guided_samples(present, groups, size, n_guided, rng) if n_guided else np.zeros((0, size), int)
        random = present[sample_minimal_sets(len(present), size, n_draw - len(guided), rng)]
        mixed = np.concatenate([guided, random])
        samples.append(mixed[rng.permutation(len(mixed))] if len(guided) else mixed)  # keep the mix when cut
    if not pairs:
        return []
    first = np.repeat([p[0] for p in pairs], n_draw)[:, None]
    second = np.repeat([p[1] for p in pairs], n_draw)[:, None]
    track = np.concatenate(samples)
    models, valid = geometry.FIT[model](tracks_xy[track, first], tracks_xy[track, second])
    models, valid = models.reshape(len(pairs), n_draw, 3, 3), valid.reshape(len(pairs), n_draw)
    residual = geometry.RESIDUAL[model]
    blocks = []
    for (m0, m1), present, pair_models, pair_valid in zip(pairs, items, models, valid):
        kept = pair_models[pair_valid][:n_hypotheses]
        if len(kept):
            blocks.append(ResidualBlock(present, residual(kept, tracks_xy[present, m0], tracks_xy[present, m1]).T))
    return blocks


def _median_per_object(errors: np.ndarray, usable: np.ndarray, track_object: np.ndarray,
                       n_objects: int) -> np.ndarray:
    """Median error of each object's usable points under each model, per pair.

    The median, not the paper's mean: a few wrongly tracked points (occlusion edges, points whose majority
    label is wrong) otherwise dominate an object's residual.

    Args:
        errors: (P, M, N) error of every point under every model, per pair.
        usable: (P, N) bool, point n is visible in both frames of pair p.
        track_object: (N,) object index of each point (-1 = none).

    Returns:
        (P, K, M) medians, NaN where an object has no usable point in a pair.
    """
    out = np.full((errors.shape[0], n_objects, errors.shape[1]), np.nan)
    for k in range(n_objects):
        idx = np.flatnonzero(track_object == k)
        if len(idx) == 0:
            continue
        masked = np.where(usable[:, None, idx], errors[:, :, idx], np.nan)
        has = usable[:, idx].any(axis=1)
        out[has, k] = np.nanmedian(masked[has], axis=2)
    return out


def _blocks_from_pairs(residuals: np.ndarray, item_present: np.ndarray, model_valid: np.ndarray,
                       energy: np.ndarray | None = None) -> list[ResidualBlock]:
    """Split (P, K, K) item × model residuals into per-pair blocks of present items and valid models."""
    blocks = []
    for p, (r, present, valid) in enumerate(zip(residuals, item_present, model_valid)):
        if not valid.any() or not present.any():
            continue
        items, owners = np.flatnonzero(present), np.flatnonzero(valid)
        blocks.append(ResidualBlock(items, r[np.ix_(items, owners)], owners,
                                    None if energy is None else energy[p, items]))
    return blocks


def _fit_members(x1: np.ndarray, x2: np.ndarray, member: np.ndarray,
                 min_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Eight-point F of every (pair, object) set from its members only.

    Sets are fitted in buckets of similar size (padded with zero-weight points to the bucket's largest), so
    the background's thousands of points do not make every small object's system as tall.

    Args:
        x1, x2: (P, N, 2) positions in the two frames of each pair; member: (P·K, N) bool, row p·K + k = the
            points of object k in pair p.

    Returns:
        F (P·K, 3, 3) and valid (P·K,); sets of fewer than min_points points are invalid (F = 0).
    """
    n_sets, n_points = member.shape
    n_objects = n_sets // x1.shape[0]
    counts = member.sum(axis=1)
    F, valid = np.zeros((n_sets, 3, 3)), np.zeros(n_sets, dtype=bool)
    order = np.argsort(~member, axis=1, kind="stable")  # each row's members first
    bucket = np.ceil(np.log2(np.maximum(counts, 1))).astype(int)
    for b in np.unique(bucket[counts >= min_points]):
        rows = np.flatnonzero((bucket == b) & (counts >= min_points))
        width = int(counts[rows].max())
        idx = order[rows, :width]
        pair = rows // n_objects
        weights = np.take_along_axis(member[rows], idx, axis=1).astype(np.float64)
        F[rows], valid[rows] = geometry.fundamental_eight_point(x1[pair[:, None], idx], x2[pair[:, None], idx],
                                                                weights)
    return F, valid


def object_epipolar_residuals(tracks_xy: np.ndarray, visible: np.ndarray, track_object: np.ndarray,
                              n_objects: int, *, gap: int, min_points: int = 8) -> list[ResidualBlock]:
    """Object-level epipolar hypotheses: one eight-point F per object per pair (m, m + gap).

    Objects with fewer than ``min_points`` trajectories in a pair (or a degenerate configuration) get no model
    in that pair but are still scored under the others' models.

    Args:
        tracks_xy: (N, F, 2) trajectory positions; visible: (N, F) bool.
        track_object: (N,) object index of each trajectory in [0, n_objects) (majority label), -1 = unused.
        n_objects: K.
        gap: frame gap of a pair.

    Returns:
        One ResidualBlock per pair: items = objects with trajectories in the pair, residuals = median Sampson
        distance (pixels²) of the object's trajectories under each valid object model of the pair.
    """
    tracks_xy, visible = _check_tracks(tracks_xy, visible)
    track_object = np.asarray(track_object)
    if track_object.shape != tracks_xy.shape[:1]:
        raise ValueError(f"track_object must be ({tracks_xy.shape[0]},), got {track_object.shape}")
    pairs = frame_pairs(tracks_xy.shape[1], gap)
    if not pairs:
        return []
    m0 = np.array([p[0] for p in pairs])
    m1 = np.array([p[1] for p in pairs])
    x1 = np.swapaxes(tracks_xy[:, m0], 0, 1)  # (P, N, 2)
    x2 = np.swapaxes(tracks_xy[:, m1], 0, 1)
    both = (visible[:, m0] & visible[:, m1]).T  # (P, N)
    member = both[:, None, :] & (track_object[None, None, :] == np.arange(n_objects)[None, :, None])
    n_pairs = len(pairs)
    x1s = np.where(both[..., None], x1, 0.0)
    x2s = np.where(both[..., None], x2, 0.0)
    F, valid = _fit_members(x1s, x2s, member.reshape(n_pairs * n_objects, -1), max(min_points, 8))
    F = F.reshape(n_pairs, n_objects, 3, 3)
    errors = geometry.sampson_distance(F, x1s, x2s)  # (P, K, N)
    medians = _median_per_object(errors, both, track_object, n_objects)
    return _blocks_from_pairs(medians, member.any(axis=2), valid.reshape(n_pairs, n_objects))


def flow_samples(labels: np.ndarray, flows: np.ndarray, step: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flow vectors on a regular grid of every ``step`` pixels, with the label of their pixel in the first frame.

    Args:
        labels: (F, H, W) int labels; flows: (F-1, H, W, 2) forward flow from frame m to m + 1.

    Returns:
        xy (G, 2) grid positions (x, y); uv (F-1, G, 2) flow vectors; lab (F-1, G) labels at frame m.
    """
    if step < 1:
        raise ValueError(f"flow grid step must be >= 1, got {step}")
    ys, xs = np.mgrid[0:labels.shape[1]:step, 0:labels.shape[2]:step]
    xy = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)
    uv = flows[:, ys.ravel(), xs.ravel()].astype(np.float64)
    lab = labels[:-1, ys.ravel(), xs.ravel()]
    return xy, uv, lab


def thinned_groups(groups: np.ndarray, n_groups: int, max_members: int) -> np.ndarray:
    """Groups thinned to at most ``max_members`` members each: every s-th member in order is kept,
    s = ceil(count / max_members); the others are set to -1.

    Args:
        groups: (N,) int group of each member in [0, n_groups), negative = none.
        n_groups: number of groups.
        max_members: most members a group keeps.

    Returns:
        (N,) int groups, -1 for the members dropped.
    """
    counts = np.bincount(groups[groups >= 0], minlength=n_groups)
    order = np.argsort(groups, kind="stable")
    ranked = groups[order]
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order)) - np.searchsorted(ranked, ranked)
    stride = np.maximum(1, -(-counts // max_members))
    keep = (groups >= 0) & (rank % stride[np.maximum(groups, 0)] == 0)
    return np.where(keep, groups, -1)


def object_flow_residuals(labels: np.ndarray, flows: np.ndarray, object_ids: np.ndarray, *, grid_step: int = 4,
                          min_vectors: int = 24, max_vectors: int | None = None) -> list[ResidualBlock]:
    """Object-level flow hypotheses: one quadratic flow model per object per consecutive pair (m, m + 1).

    Args:
        labels: (F, H, W) int per-frame instance ids.
        flows: (F-1, H, W, 2) forward flow.
        object_ids: (K,) the ids that are items, in item order; pixels with other ids are ignored.
        grid_step: flow vectors are read every grid_step pixels.
        min_vectors: fewer vectors than this (per object and pair) give no model of the object in that pair.
        max_vectors: an object's vectors in a pair thinned to at most this many (``thinned_groups``; None: all):
            the background holds most of the grid, and its twelve parameters and mean error need far fewer.

    Returns:
        One ResidualBlock per pair: items = objects with flow vectors in the pair, residuals = mean squared
        flow error (pixels²) under each valid object model of the pair, energy = each object's mean |uv|².
    """
    labels = np.asarray(labels)
    flows = np.asarray(flows)
    if labels.ndim != 3 or flows.shape != (labels.shape[0] - 1, *labels.shape[1:], 2):
        raise ValueError(f"flows must be (F-1, H, W, 2) for labels (F, H, W) = {labels.shape}, got {flows.shape}")
    object_ids = np.asarray(object_ids)
    n_objects, n_pairs = len(object_ids), flows.shape[0]
    xy, uv, lab = flow_samples(labels, flows, grid_step)
    order = np.argsort(object_ids)
    pos = np.searchsorted(object_ids[order], lab).clip(0, n_objects - 1)
    obj = np.where(object_ids[order][pos] == lab, order[pos], -1)  # (P, G) item index or -1
    ok = np.all(np.isfinite(uv), axis=-1) & (obj >= 0)
    groups = np.where(ok, np.arange(n_pairs)[:, None] * n_objects + obj, -1).ravel()
    if max_vectors is not None:
        groups = thinned_groups(groups, n_pairs * n_objects, max_vectors)
    height, width = labels.shape[1:]
    stats = flow_model.flow_statistics(np.broadcast_to(xy, uv.shape).reshape(-1, 2),
                                       np.nan_to_num(uv).reshape(-1, 2), groups, n_pairs * n_objects,
                                       (width, height))
    stats = stats.reshape(n_pairs, n_objects)
    params, valid = flow_model.fit_quadratic_flow(stats, min_vectors=min_vectors)
    residuals = flow_model.flow_residual_matrix(stats, params)  # (P, K, K)
    with np.errstate(invalid="ignore", divide="ignore"):
        energy = stats.energy / stats.count
    return _blocks_from_pairs(residuals, stats.count > 0, valid, energy)
