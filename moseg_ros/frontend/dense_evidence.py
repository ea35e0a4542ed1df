"""Stage 2b, dense evidence: the pixels whose dense flow leaves the camera's epipolar geometry or its depth order.

Runs on the refit's worker (or inline). The forward and backward DIS flows of one frame pair give the epipolar
residual of every pixel (core/baseline.py); the mask keeps the reliable pixels above its threshold beyond
``dense_allowance`` of their flow, the pixels behind infinity (``dense_cheir_px``) and those nearer than the road
under them (``dense_footing``), and, with ``dense_hysteresis``, the last mask's regions that touch this one.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from moseg_ros.core.baseline import EpipolarResidual, epipolar_residual
from moseg_ros.core.track_tests.cheirality import DenseParallax, behind_infinity, dense_parallax
from moseg_ros.core.track_tests.epipolar import beyond_allowance
from moseg_ros.core.track_tests.footing import nearer_than_road
from moseg_ros.frontend.flow import DenseFlow
from moseg_ros.frontend.memory import carried
from moseg_ros.frontend.motion_config import MotionFrontEndConfig
from moseg_ros.frontend.observe import Observation, scaled_to
from moseg_ros.frontend.hulls import touching
from moseg_ros.frontend.track_evidence import rotation_limit
from moseg_ros.timing import Stages


class DenseEvidence:
    """The dense residual mask of one observation and its depth-tested part; keeps the last mask for hysteresis."""

    def __init__(self, config: MotionFrontEndConfig, flow: DenseFlow) -> None:
        self.config = config
        self._flow = flow  # the worker's own: a DIS instance is not to be shared between threads
        self.reset()

    def reset(self) -> None:
        """Forget the last dense mask."""
        # The last refit's own dense mask (before hysteresis) and its frame.
        self._last_dense: tuple[int, np.ndarray] | None = None

    def fit(self, observation: Observation,
            stages: Stages) -> tuple[EpipolarResidual | None, np.ndarray | None, np.ndarray | None]:
        """The dense residual of the observation's frame pair, its dense mask and the part the depth tests flagged.

        Args:
            observation: the frame's observation (its flows and grey frames).
            stages: timer the work is recorded in (dense_flow, dense_fit).

        Returns:
            The EpipolarResidual (None without the pair's flow), the (h, w) bool dense mask (with hysteresis) and
            its (h, w) bool part the depth tests flagged (both None without a residual).
        """
        evidence = None
        if observation.flows is not None:
            backward, forward = observation.flows
            if forward is None:
                with stages("dense_flow"):
                    forward = self._flow(observation.earlier, observation.gray)
            with stages("dense_fit"):
                evidence = self._counted(epipolar_residual(backward, forward, self.config.dense_baseline), backward)
        if evidence is None:
            return None, None, None
        with stages("dense_fit"):
            moving, depth = self._dense_mask(observation, evidence)
            return evidence, self._held(moving, observation), depth

    def _held(self, dense: np.ndarray, observation: Observation) -> np.ndarray:
        """``dense`` with the regions of the last refit's dense mask, carried to this frame, that touch it
        (``dense_hysteresis``); as it is when the flows back to that refit are no longer held."""
        last, self._last_dense = self._last_dense, (observation.index, dense)
        if not self.config.dense_hysteresis or last is None or last[1].shape != dense.shape:
            return dense
        frames = [frame for frame, _ in observation.backward]
        if not frames or frames[0] > last[0] + 1:
            return dense
        return dense | touching(carried(last[1], last[0], observation.backward), dense)

    def _reliable(self, gray: np.ndarray, flow: np.ndarray) -> np.ndarray:
        """(h, w) bool: pixels whose dense flow the residual test may trust: textured ones (the smaller
        structure-tensor eigenvalue above ``min_texture``), and smooth ones within ``texture_reach`` of texture
        whose ``flow`` (h, w, 2) is at most ``smooth_max_flow`` long."""
        textured = (cv2.cornerMinEigenVal(gray, 5, 3) > self.config.min_texture).astype(np.uint8)
        if self.config.texture_reach <= 0:
            return textured > 0
        side = 2 * self.config.texture_reach + 1
        near = cv2.dilate(textured, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (side, side))) > 0
        slow = np.hypot(flow[..., 0], flow[..., 1]) <= self.config.smooth_max_flow
        return (textured > 0) | (near & slow)

    def _counted(self, evidence: EpipolarResidual, flow: np.ndarray) -> EpipolarResidual:
        """``evidence`` whose residual counts only beyond ``dense_allowance`` of each pixel's ``flow`` (h, w, 2),
        for the dense mask and the tracks' corroboration alike; a homography's transfer error stays whole: it has
        no epipolar line to be off."""
        if evidence.homography is not None or self.config.dense_allowance <= 0:
            return evidence
        return replace(evidence, residual=beyond_allowance(evidence.residual, flow, self.config.dense_allowance))

    def _dense_mask(self, observation: Observation, evidence: EpipolarResidual) -> tuple[np.ndarray, np.ndarray]:
        """(h, w) bool the dense mask of ``evidence`` (the module's docstring), and its part the depth tests flagged
        (``_against_parallax``)."""
        backward, _ = observation.flows
        gray = observation.gray
        depth = np.zeros(gray.shape, dtype=bool)
        if evidence.fundamental is None and evidence.homography is None:
            return depth, depth
        moving = (evidence.residual > evidence.threshold) & evidence.valid
        reliable = self._reliable(gray, backward) if self.config.min_texture > 0 else None
        if reliable is not None:
            moving &= reliable
        if evidence.homography is None and (self.config.dense_cheir_px > 0 or self.config.dense_footing):
            K = scaled_to(observation.camera_matrix, observation.tracking_shape, gray.shape)
            limit = rotation_limit(self.config.track_motion, self.config.dense_gap)
            parallax = dense_parallax(backward, evidence.valid, evidence.fundamental, K, self.config.track_motion,
                                      inlier_px=self.config.dense_baseline.ransac_threshold_px, max_rotation_deg=limit)
            if parallax is not None:
                depth = self._against_parallax(parallax, evidence.valid, reliable)
                moving |= depth
        return moving, depth

    def _against_parallax(self, parallax: DenseParallax, valid: np.ndarray,
                          reliable: np.ndarray | None = None) -> np.ndarray:
        """(h, w) bool: the pixels the dense parallax puts behind infinity (``dense_cheir_px``; in regions that
        reach ``reliable`` ones, ``_reliable``, None: all) or, of the reliable ones, nearer than the road under them
        (``dense_footing``)."""
        moving = np.zeros(valid.shape, dtype=bool)
        if self.config.dense_cheir_px > 0:
            # Not gated by texture: a followed object's body is often smooth, and its flow is ~0 there. But only
            # the regions that reach pixels whose flow is reliable: in the middle of a blank sky DIS's flow is
            # interpolated, and a patch of it came out behind infinity (docs/experiments.md).
            behind = behind_infinity(parallax, valid, self.config.track_motion,
                                     threshold_px=self.config.dense_cheir_px, guarded=True)
            moving |= behind if reliable is None else touching(behind, behind & reliable)
        near = (nearer_than_road(parallax, valid, self.config.track_motion, excess_px=self.config.dense_footing_px,
                                 clearance=self.config.dense_footing_clearance)
                if self.config.dense_footing else None)
        if near is None:
            return moving
        # Gated as the residual is: the smooth panes of near parked cars' windows came out nearer than the road
        # under them (docs/experiments.md, ``dense_footing``); an oncoming car's smooth body keeps its pixels near
        # texture while its flow is small (``smooth_max_flow``).
        return moving | (near if reliable is None else near & reliable)
