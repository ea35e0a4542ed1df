"""Stage 2, motion evidence: one observation's track flags and dense mask, handed on as an immutable ``Refit``.

``MotionEvidence`` is the worker's side of the front-end (it runs on the refit's worker, or inline): it holds
the track test's window (``TrackEvidence``) and the dense test's last mask (``DenseEvidence``) and touches no
state of the frame path. ``refit_tracks`` comes first and is handed over alone when time is short; its epipolar
distances are corroborated by the last dense residual, and it carries the last dense mask on.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from moseg_ros.core.baseline import EpipolarResidual
from moseg_ros.frontend.dense_evidence import DenseEvidence
from moseg_ros.frontend.flow import DenseFlow
from moseg_ros.frontend.motion_config import MotionFrontEndConfig
from moseg_ros.frontend.observe import Observation
from moseg_ros.frontend.track_evidence import TrackEvidence
from moseg_ros.timing import Stages

# The label of the depth tests' pixels in ``dense_labels`` (1: the rest of the dense mask).
DEPTH_LABEL = 2


def dense_labels(refit: Refit) -> np.ndarray:
    """A refit's dense mask as labels, to be carried along the flow as one.

    Args:
        refit: a Refit with a dense mask.

    Returns:
        (h, w) uint8: DEPTH_LABEL where the depth tests flagged a pixel (``Refit.dense_depth``, a part of the
        mask), 1 elsewhere in the mask, 0 outside.
    """
    labels = refit.dense.astype(np.uint8)
    if refit.dense_depth is not None:
        labels[refit.dense_depth] = DEPTH_LABEL
    return labels


@dataclass(frozen=True)
class Refit:
    """The motion evidence fitted on one observation: which tracks move, and the dense residual mask.

    Attributes:
        index: the frame of the track test.
        flagged: (n,) ids of the tracks that move.
        dense: (h, w) bool dense residual mask of frame ``dense_index``, or None.
        stages: seconds of the work done for frame ``index``, by stage.
        dense_index: the dense mask's frame: ``index`` when both were fitted on it; an earlier frame's when the
            track test comes first (see ``MotionFrontEnd.refit_tracks``); -1 with no dense mask yet.
        dense_depth: (h, w) bool part of ``dense`` the depth tests flagged, or None.
        dense_planar: whether the dense residual was against a homography.
        depth_flagged: (d,) ids of the flagged tracks that the depth tests flagged (``depth_moving``), now or
            while they have stayed flagged since.
    """

    index: int
    flagged: np.ndarray
    dense: np.ndarray | None
    stages: dict[str, float]
    dense_index: int
    dense_depth: np.ndarray | None = None
    dense_planar: bool = False
    depth_flagged: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


class MotionEvidence:
    """The fits and tests of each observation: the track test, then the dense one (the worker's state only)."""

    def __init__(self, config: MotionFrontEndConfig, flow: DenseFlow) -> None:
        self.tracks = TrackEvidence(config)
        self.dense = DenseEvidence(config, flow)
        self.reset()

    def reset(self) -> None:
        """Forget the window's pair fits, the sticky flags and the last dense mask."""
        self.tracks.reset()
        self.dense.reset()
        # The last dense residual (its frame, EpipolarResidual), which corroborates the next track tests, and the
        # last refit with a dense mask, whose dense part the next track tests' refits carry on.
        self._residual: tuple[int, EpipolarResidual] | None = None
        self._published_dense: Refit | None = None

    def refit(self, observation: Observation) -> Refit:
        """The fits and tests of one observation: ``refit_tracks`` then ``refit_dense``."""
        return self.refit_dense(observation, self.refit_tracks(observation))

    def refit_tracks(self, observation: Observation) -> Refit:
        """The track test of one observation (the window's pairs with sticky flags), its epipolar distances
        corroborated by the last dense residual; the Refit carries the last dense mask (``dense_index``: its
        frame). The cheaper half of a refit, and the one whose age costs: stale track flags lose movers that a
        dense mask as stale keeps (docs/experiments.md, ``refit``), so a background worker hands it over before it
        fits the dense half."""
        stages = Stages()
        with stages("fit"):
            flagged, depth = self.tracks.flagged(observation, self._residual)
        if self._published_dense is None:
            return Refit(observation.index, flagged, None, stages.seconds, -1, depth_flagged=depth)
        return replace(self._published_dense, index=observation.index, flagged=flagged, depth_flagged=depth,
                       stages=stages.seconds)

    def refit_dense(self, observation: Observation, tracks: Refit) -> Refit:
        """``tracks`` (this observation's ``refit_tracks``) with this observation's dense residual mask, whose
        residual corroborates the next track tests; ``stages`` adds dense_flow and dense_fit."""
        stages = Stages()
        evidence, dense, depth = self.dense.fit(observation, stages)
        self._residual = None if evidence is None else (observation.index, evidence)
        planar = evidence is not None and evidence.homography is not None
        refit = replace(tracks, dense=dense, dense_index=observation.index, dense_depth=depth, dense_planar=planar,
                        stages={**tracks.stages, **stages.seconds})
        self._published_dense = None if dense is None else refit
        return refit
