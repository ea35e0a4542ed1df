"""The paper's object-level method: a window of objects -> which of them move (``segment_objects``).

Per object an epipolar model on its trajectories and a quadratic flow model on its flow over the window, the two
ORK affinities fused by co-regularized spectral clustering, and the background's cluster; the trajectory-level
method is core/trajectory_segment.py.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from moseg_ros.core import affinity, clustering, ground_contact, hypotheses


OBJECT_VIEWS = ("epipolar", "flow")


@dataclass(frozen=True)
class SegmentConfig:
    """Settings of the object-level method.

    Attributes:
        gap: frame gap of the epipolar (F) pairs (m, m + gap); flow models use consecutive frames.
        flow_step: flow vectors are read on a grid of this step (pixels).
        min_tracks: fewest trajectories of an object in a pair for its own F model (eight-point: 8).
        min_flow_vectors: fewest flow vectors of an object in a pair for its own flow model.
        max_flow_vectors: an object's flow vectors in a pair thinned to at most this many (None: all of them).
        inlier_ratio: ORK inliers of an object are the models within this factor of its own-model residual.
        epipolar_floor: noise floor of the median Sampson distance (pixels²).
        flow_floor: noise floor of the mean squared flow error (pixels²).
        flow_energy_fraction: the flow reference of an object is also at least this fraction of its mean
            squared flow: a static object at another depth than the model assumes has a flow error of the
            order of its own flow (parallax), a moving one can have a far larger error than its flow.
        lam: co-regularization weight λ.
        n_iter: co-regularization rounds.
        k_max: largest number of motions considered when estimating it; None: as many as the window has
            objects (a cap below that makes k-means merge objects with no affinity to each other, and a mover
            merged into the background's cluster is taken back).
        tie_tolerance: eigengaps this close to the largest are ties, resolved towards more motions: when the
            views disagree about an object (epipolar: consistent with the camera; flow: not) it is reported
            as moving (see segment_objects).
        ground_contact: decide objects that stand on a visible ground plane by the ground-contact test
            (core/ground_contact.py) instead of by their motion cluster; None switches the test off (the paper alone).
    """

    gap: int = 2
    flow_step: int = 4
    min_tracks: int = 8
    min_flow_vectors: int = 24
    max_flow_vectors: int | None = None
    inlier_ratio: float = 4.0
    epipolar_floor: float = 1.0
    flow_floor: float = 0.25
    flow_energy_fraction: float = 0.15
    lam: float = 0.1
    n_iter: int = 5
    k_max: int | None = None
    tie_tolerance: float = 0.05
    ground_contact: ground_contact.GroundConfig | None = field(default_factory=ground_contact.GroundConfig)


@dataclass(frozen=True)
class ObjectSegmentation:
    """Result of segment_objects for K objects.

    Attributes:
        object_ids: (K,) instance ids (0 = the background pseudo-object, always first).
        cluster: (K,) motion cluster of each object in [0, n_motions).
        background_cluster: the cluster of the camera's own motion (the one holding object 0).
        dynamic: (K,) True for moving objects: outside the background cluster or, for objects with a ground
            contact score, a score above 1.
        confidence: (K,) in [0, 1], how clearly each object sits in its cluster rather than the nearest
            competing one, or how far its contact score is from 1 (see segment_objects).
        n_motions: number of motion clusters.
        contact: (K,) ground-contact score of each object (core/ground_contact.py; NaN = no contact seen or test off).
    """

    object_ids: np.ndarray
    cluster: np.ndarray
    background_cluster: int
    dynamic: np.ndarray
    confidence: np.ndarray
    n_motions: int
    contact: np.ndarray


def track_objects(labels: np.ndarray, tracks_xy: np.ndarray, visible: np.ndarray,
                  object_ids: np.ndarray) -> np.ndarray:
    """Object index of each trajectory: the label it falls in most often over its visible frames.

    Args:
        labels: (F, H, W) instance ids; tracks_xy: (N, F, 2) (x, y) pixels; visible: (N, F) bool.
        object_ids: (K,) sorted ids that are items.

    Returns:
        (N,) index into object_ids, or -1 for trajectories never seen on an item (or outside the image).
    """
    n_frames, height, width = labels.shape
    xi = np.rint(np.nan_to_num(tracks_xy[..., 0], nan=-1.0)).astype(np.int64)
    yi = np.rint(np.nan_to_num(tracks_xy[..., 1], nan=-1.0)).astype(np.int64)
    inside = visible & (xi >= 0) & (xi < width) & (yi >= 0) & (yi < height)
    frame = np.broadcast_to(np.arange(n_frames), xi.shape)
    lab = labels[frame[inside], yi[inside], xi[inside]]
    pos = np.searchsorted(object_ids, lab).clip(0, len(object_ids) - 1)
    known = object_ids[pos] == lab
    votes = np.zeros((tracks_xy.shape[0], len(object_ids)), dtype=np.int64)
    np.add.at(votes, (np.nonzero(inside)[0][known], pos[known]), 1)
    return np.where(votes.sum(axis=1) > 0, votes.argmax(axis=1), -1)


def _check_window(labels: np.ndarray, flows: np.ndarray, tracks_xy: np.ndarray,
                  tracks_visible: np.ndarray) -> None:
    if labels.ndim != 3 or labels.shape[0] < 2:
        raise ValueError(f"labels must be (F, H, W) with F >= 2, got {labels.shape}")
    if not np.issubdtype(labels.dtype, np.integer):
        raise ValueError(f"labels must be integer ids, got {labels.dtype}")
    if labels.size and labels.min() < 0:
        raise ValueError(f"labels must be ids >= 0 (0 = background), got {labels.min()}")
    if flows.shape != (labels.shape[0] - 1, *labels.shape[1:], 2):
        raise ValueError(f"flows must be {(labels.shape[0] - 1, *labels.shape[1:], 2)}, got {flows.shape}")
    if tracks_xy.ndim != 3 or tracks_xy.shape[1:] != (labels.shape[0], 2):
        raise ValueError(f"tracks_xy must be (N, {labels.shape[0]}, 2), got {tracks_xy.shape}")
    if tracks_visible.shape != tracks_xy.shape[:2]:
        raise ValueError(f"tracks_visible must be {tracks_xy.shape[:2]}, got {tracks_visible.shape}")


def _confidence(embedding: np.ndarray, cluster: np.ndarray, background: int) -> np.ndarray:
    """1 − d_own / (d_own + d_alt) in the row-normalized embedding.

    d_own: distance to the centre of the object's cluster; d_alt: to the background cluster's centre for a
    dynamic object, to the nearest other cluster's centre for a static one.
    """
    k = int(cluster.max()) + 1
    centres = np.stack([embedding[cluster == c].mean(axis=0) for c in range(k)])
    dist = np.linalg.norm(embedding[:, None, :] - centres[None], axis=2)
    own = dist[np.arange(len(cluster)), cluster]
    alt_dist = dist.copy()
    alt_dist[np.arange(len(cluster)), cluster] = np.inf
    alt = np.where(cluster != background, dist[:, background], alt_dist.min(axis=1))
    return np.clip(1.0 - own / np.maximum(own + alt, 1e-12), 0.0, 1.0)


def _decide_by_contact(dynamic: np.ndarray, confidence: np.ndarray,
                       contact: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Objects with a ground-contact score are moving exactly when it exceeds 1, with confidence
    |s − 1| / max(s, 1) (0 at the threshold, 1 for a foot that moves exactly with the ground); the others
    keep their cluster's decision."""
    seen = np.isfinite(contact)
    score = np.where(seen, contact, 1.0)
    dynamic = np.where(seen, score > 1.0, dynamic)
    confidence = np.where(seen, np.abs(score - 1.0) / np.maximum(score, 1.0), confidence)
    return dynamic, confidence


def _view_affinities(blocks: dict[str, list[hypotheses.ResidualBlock]], views: tuple[str, ...], n_items: int,
                     config: SegmentConfig) -> tuple[list[np.ndarray], np.ndarray]:
    """One ORK affinity per view, with items that have no data in a view filled in.

    An object without data in a view (no trajectories, or too small for flow vectors) is not evidence of a
    separate motion: its row is taken from the mean of the views that saw it, and an object no view saw gets
    the background's row (it behaves as a copy of the background: static, confidence 0). Returns the
    affinities and the (K,) mask of unseen items.
    """
    floors = {"epipolar": config.epipolar_floor, "flow": config.flow_floor}
    affinities, seen = [], []
    for v in views:
        a = affinity.ordered_residual_kernel(blocks[v], n_items, inlier_ratio=config.inlier_ratio,
                                             noise_floor=floors[v], energy_fraction=config.flow_energy_fraction)
        mask = np.zeros(n_items, dtype=bool)
        for block in blocks[v]:
            mask[block.items] = True
        affinities.append(a)
        seen.append(mask)
    seen_arr = np.array(seen)
    unseen = ~seen_arr.any(axis=0)
    filled = []
    for v, a in enumerate(affinities):
        a = a.copy()
        others = [w for w in range(len(views)) if w != v]
        for i in np.flatnonzero(~seen_arr[v]):
            donors = [w for w in others if seen_arr[w, i]]
            if donors:
                row = np.mean([affinities[w][i] for w in donors], axis=0)
            else:  # a copy of the background: tied to it and to whatever it is tied to
                row = a[0].copy()
                row[0] = 1.0
            a[i, :] = row
            a[:, i] = row
        np.fill_diagonal(a, 1.0)  # every object supports itself
        filled.append(a)
    return filled, unseen


def object_residual_blocks(labels: np.ndarray, flows: np.ndarray, tracks_xy: np.ndarray,
                           tracks_visible: np.ndarray, object_ids: np.ndarray, views: tuple[str, ...],
                           config: SegmentConfig) -> dict[str, list[hypotheses.ResidualBlock]]:
    """Per-view residual blocks of the objects (item k = object_ids[k]).

    Args:
        labels: (F, H, W) int per-frame instance ids.
        flows: (F-1, H, W, 2) forward flow between consecutive frames.
        tracks_xy: (N, F, 2) trajectory positions (x, y) in pixels.
        tracks_visible: (N, F) bool.
        object_ids: (K,) sorted ids that are items.
        views: subset of ("epipolar", "flow").
        config: settings.

    Returns:
        {view: residual blocks} (``hypotheses.object_epipolar_residuals``, ``hypotheses.object_flow_residuals``).
    """
    blocks = {}
    if "epipolar" in views:
        owner = track_objects(labels, tracks_xy, tracks_visible, object_ids)
        blocks["epipolar"] = hypotheses.object_epipolar_residuals(
            tracks_xy, tracks_visible, owner, len(object_ids), gap=min(config.gap, labels.shape[0] - 1),
            min_points=config.min_tracks)
    if "flow" in views:
        blocks["flow"] = hypotheses.object_flow_residuals(labels, flows, object_ids, grid_step=config.flow_step,
                                                          min_vectors=config.min_flow_vectors,
                                                          max_vectors=config.max_flow_vectors)
    return blocks


def segment_objects(labels: np.ndarray, flows: np.ndarray, tracks_xy: np.ndarray, tracks_visible: np.ndarray, *,
                    views: tuple[str, ...] = OBJECT_VIEWS, n_motions: int | None = None,
                    config: SegmentConfig | None = None,
                    rng: np.random.Generator | None = None) -> ObjectSegmentation:
    """Group the objects of a window by motion and say which move independently of the camera (the paper).

    Items are the instance ids present in ``labels`` plus the background pseudo-object 0 (always item 0);
    each trajectory belongs to the id it falls in most often over its visible frames.

    Views: "epipolar" (an eight-point F per object per frame pair (m, m + gap); residual = median Sampson
    distance of an object's trajectories) and "flow" (a quadratic flow model per object per consecutive pair
    on a grid of flow vectors; residual = mean squared error). Objects with fewer than ``min_tracks``
    trajectories (or ``min_flow_vectors`` vectors) in a pair get no model there but are still scored.

    Per view an ORK affinity; an object's inliers are the models m with

        r_km <= inlier_ratio · max(r_k,own, floor, flow_energy_fraction · mean |uv|²)   (energy term: flow only).

    An object without data in a view takes its row from the other view (or from the background, confidence
    0, if no view saw it). The views are fused by co-regularized spectral clustering; K comes from the
    eigengap of the mean normalized affinity (K = 1 possible: nothing moves; ties towards more motions)
    unless given. The background cluster is the one holding object 0; every object outside it is dynamic,
    except that objects standing on a visible ground plane are decided by the ground-contact test
    (core/ground_contact.py; ``config.ground_contact``, None = the paper alone): moving exactly when their
    contact score exceeds 1. The background pseudo-object spans ground, facades and sky at every depth, so no
    one flow model describes it and the flow view alone takes depth for motion; the ground plane gives the
    depth at each object's foot: with the test far more of the moving objects and fewer of the static ones are
    flagged (docs/experiments.md, ``ground_contact``).

    Small cases: one item (only the background) or n_motions = 1 -> nothing dynamic, confidence 1. Two items
    (background and one object) go through the same path: the object is dynamic exactly when its affinity to
    the background is low enough for the eigengap to choose K = 2 (always, if n_motions = 2 is given).

    Confidence: 1 − d_own / (d_own + d_alt) in the fused spectral embedding, d_own the distance to the
    object's cluster centre, d_alt to the background's centre (dynamic objects) or to the nearest other
    centre (static ones); 1 when K = 1; |s − 1| / max(s, 1) for an object decided by its contact score s.

    Args:
        labels: (F, H, W) int per-frame instance ids (0 = background, ids stable over time).
        flows: (F-1, H, W, 2) float forward flow between consecutive frames.
        tracks_xy: (N, F, 2) float trajectory positions (x, y) in pixels.
        tracks_visible: (N, F) bool.
        views: any non-empty subset of ("epipolar", "flow") (the ablation switch).
        n_motions: number of motions, or None to estimate it.
        config: settings (default SegmentConfig()).
        rng: random generator for k-means.

    Returns:
        ObjectSegmentation of the K items.
    """
    config = config or SegmentConfig()
    rng = rng if rng is not None else np.random.default_rng(0)
    views = tuple(views)
    if not views or set(views) - set(OBJECT_VIEWS) or len(set(views)) != len(views):
        raise ValueError(f"views must be a non-empty subset of {OBJECT_VIEWS}, got {views}")
    labels = np.asarray(labels)
    flows = np.asarray(flows)
    tracks_xy = np.asarray(tracks_xy, dtype=np.float64)
    tracks_visible = np.asarray(tracks_visible, dtype=bool)
    _check_window(labels, flows, tracks_xy, tracks_visible)
    object_ids = np.union1d([0], np.unique(labels[labels > 0])).astype(np.int64)  # the mask first: mostly 0
    n_items = len(object_ids)
    if n_motions is not None and not 1 <= n_motions <= n_items:
        raise ValueError(f"n_motions must be in [1, {n_items}] for {n_items} objects, got {n_motions}")

    contact = np.full(n_items, np.nan)
    if config.ground_contact is not None and n_items > 1:
        contact[1:] = ground_contact.contact_scores(labels, flows, object_ids[1:], config.ground_contact)

    def result(cluster: np.ndarray, confidence: np.ndarray) -> ObjectSegmentation:
        background = int(cluster[0])
        dynamic, confidence = _decide_by_contact(cluster != background, confidence.astype(np.float64), contact)
        return ObjectSegmentation(object_ids, cluster.astype(np.int64), background, dynamic, confidence,
                                  int(cluster.max()) + 1, contact)

    if n_items == 1 or n_motions == 1:
        return result(np.zeros(n_items, dtype=np.int64), np.ones(n_items))
    blocks = object_residual_blocks(labels, flows, tracks_xy, tracks_visible, object_ids, views, config)
    affinities, unseen = _view_affinities(blocks, views, n_items, config)
    k_max = n_items if config.k_max is None else min(config.k_max, n_items)
    k = n_motions if n_motions is not None else clustering.estimate_n_motions(
        affinities, k_min=1, k_max=k_max, tie_tolerance=config.tie_tolerance)
    if k == 1:
        return result(np.zeros(n_items, dtype=np.int64), np.where(unseen, 0.0, 1.0))
    embedding = clustering.coregularized_embedding(affinities, k, lam=config.lam, n_iter=config.n_iter)
    joint = clustering.row_normalize(np.concatenate([clustering.row_normalize(u) for u in embedding], axis=1))
    cluster = clustering.kmeans(joint, k, rng)
    # Number clusters by first item so that the background's cluster comes first.
    _, first = np.unique(cluster, return_index=True)
    cluster = np.argsort(np.argsort(first))[np.unique(cluster, return_inverse=True)[1]]
    confidence = _confidence(joint, cluster, int(cluster[0]))
    confidence[unseen] = 0.0
    return result(cluster, confidence)
