"""The ground-contact test (moseg_ros.core.ground) on exact plane flows with known answers."""

import cv2
import numpy as np
import pytest

from moseg_ros.core import ground_contact as ground

HEIGHT, WIDTH = 120, 200
# Forward motion over a ground plane seen by a camera looking ahead: points low in the image move down and out.
GROUND_H = np.array([[1.02, 0.0, -2.0], [0.0, 1.03, -1.5], [0.0, 1.0e-4, 1.0]])


def plane_flow(homography: np.ndarray, height: int = HEIGHT, width: int = WIDTH) -> np.ndarray:
    """(H, W, 2) flow H(x) − x of every pixel."""
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
    x = np.stack([xs.ravel(), ys.ravel()], axis=1)
    moved = cv2.perspectiveTransform(x[None], homography)[0]
    return (moved - x).reshape(height, width, 2).astype(np.float32)


def street_pair() -> tuple[np.ndarray, np.ndarray]:
    """Labels and flow of one pair: ground everywhere; object 1 static (every pixel moves like the ground at
    its foot, as an upright face does), object 2 keeps its distance (zero flow, like a car ahead at the
    camera's speed), object 3 is cut by the bottom border, object 4 is 3 columns wide."""
    labels = np.zeros((HEIGHT, WIDTH), dtype=np.int32)
    flow = plane_flow(GROUND_H)
    labels[60:90, 20:60] = 1
    flow[60:90, 20:60] = flow[90, 20:60]  # the ground's flow at the foot row, copied up the face
    labels[50:80, 100:140] = 2
    flow[50:80, 100:140] = 0.0
    labels[95:, 160:190] = 3
    labels[60:85, 70:73] = 4
    flow[60:85, 70:73] = flow[85, 70:73]
    return labels, flow


def test_fit_recovers_the_ground_homography():
    labels, flow = street_pair()
    fitted = ground.fit_ground_homography(labels, flow, ground.GroundConfig())
    assert fitted is not None
    np.testing.assert_allclose(fitted / fitted[2, 2], GROUND_H, atol=1e-4)


def test_no_ground_without_a_dominant_plane():
    rng = np.random.default_rng(0)
    labels = np.zeros((HEIGHT, WIDTH), dtype=np.int32)
    flow = rng.uniform(-20, 20, (HEIGHT, WIDTH, 2)).astype(np.float32)
    assert ground.fit_ground_homography(labels, flow, ground.GroundConfig()) is None
    labels[:] = 7  # no background at all
    assert ground.fit_ground_homography(labels, plane_flow(GROUND_H), ground.GroundConfig()) is None


def test_foot_pixels_need_background_below_inside_the_image():
    labels = np.zeros((20, 6), dtype=np.int32)
    labels[5:10, 0:2] = 1   # ground below: foot at row 9
    labels[5:10, 2:4] = 2
    labels[10:12, 2:4] = 3  # object 3 right below object 2: object 3's foot at row 11, none for object 2
    labels[12:20, 4:6] = 4  # reaches the bottom border: no foot
    rows, cols = ground.foot_pixels(labels, clearance=3)
    assert sorted(zip(rows.tolist(), cols.tolist())) == [(9, 0), (9, 1), (11, 2), (11, 3)]


def test_static_foot_scores_low_and_sliding_foot_high():
    labels, flow = street_pair()
    n_frames = 4
    labels_w = np.repeat(labels[None], n_frames, axis=0)
    flows_w = np.repeat(flow[None], n_frames - 1, axis=0)
    scores = ground.contact_scores(labels_w, flows_w, np.array([1, 2, 3, 4]))
    assert scores[0] < 0.1                                   # static: its foot moves with the ground
    assert scores[1] > 1.0                                   # its foot stands still while the ground moves
    assert np.isnan(scores[2]) and np.isnan(scores[3])       # cut by the border; too thin


def test_one_pair_of_contact_is_not_enough():
    labels, flow = street_pair()
    config = ground.GroundConfig()
    scores = ground.contact_scores(labels[None].repeat(2, axis=0), flow[None], np.array([1, 2]), config)
    assert np.isnan(scores).all()  # min_pairs = 2


def test_inconsistent_settings_are_refused():
    with pytest.raises(ValueError, match="ground_rows"):
        ground.GroundConfig(clearance=3, ground_rows=(3, 6))
    with pytest.raises(ValueError, match="probe_rows"):
        ground.GroundConfig(probe_rows=(4, 2))
