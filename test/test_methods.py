"""The method plug-ins: one registry, one interface, the default finds movers without instances."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import textured_frames
from moseg_ros.frontend.flow import DIS_PRESETS
from moseg_ros.methods import DEFAULT_METHOD, METHODS, method_class
from moseg_ros.methods.base import Decision, FrameInput, Status
from moseg_ros.frontend.instance_decisions import (OWN_REGION_BASE, InstanceDecisions, held_instances,
                                                   published_regions, with_unknown_regions)
from moseg_ros.pipeline import Pipeline, PipelineConfig


def test_registry_names_match_and_the_default_needs_no_instances():
    assert DEFAULT_METHOD == "moving_objects" == PipelineConfig().method
    assert set(METHODS) == {"epipolar_baseline", "moving_objects", "object_level"}
    assert all(method_class(name).name == name for name in METHODS)


def method_contract(cls: type, config: PipelineConfig) -> list[Decision]:
    """What the pipeline asks of every method, checked on a camera panning over texture with a block sliding across
    it (conftest.textured_frames): the first frame of a stream is a warm-up, every decision is a Decision whose
    labels have the working size and whose moving ids are labels of the frame, ``reset`` starts a new stream and
    ``close`` ends the method. Returns the decisions of the first stream."""
    assert cls.name and cls.flow_preset in DIS_PRESETS
    assert cls.__doc__ and cls.step.__doc__ and cls.reset.__doc__
    method = cls(config)
    frames = [f[..., 0].copy() for f in textured_frames(4)]
    decisions = [method.step(FrameInput(f, f.shape)) for f in frames]
    assert all(isinstance(d, Decision) for d in decisions)
    assert decisions[0].status is Status.WARMUP
    assert all(d.labels.shape == frames[0].shape for d in decisions)
    assert all(np.isin(d.dynamic_ids, d.labels).all() for d in decisions)
    method.reset()
    assert method.step(FrameInput(frames[0], frames[0].shape)).status is Status.WARMUP
    method.close()
    return decisions


@pytest.mark.parametrize("name", sorted(METHODS))
def test_every_method_keeps_the_contract(name):
    method_contract(method_class(name), PipelineConfig(method=name))


# A whole method in one file, as a newcomer would add it to moseg_ros/methods/: pixels whose grey level changed by
# more than 40 since the frame before move (a camera that stands still).
EXAMPLE_METHOD = '''
"""frame_difference: pixels whose grey level changed since the frame before move."""

import cv2
import numpy as np

from moseg_ros.methods.base import Decision, FrameInput, Status


class FrameDifference:
    """Moving regions where |frame - the frame before| exceeds 40 grey levels."""

    name = "frame_difference"
    flow_preset = "fast"

    def __init__(self, config) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget the frame before."""
        self._before = None

    def step(self, frame: FrameInput) -> Decision:
        """Label the changed pixels' connected regions; all of them move."""
        before, self._before = self._before, frame.gray
        if before is None:
            return Decision(np.zeros(frame.working_size, dtype=np.int32), status=Status.WARMUP)
        changed = (cv2.absdiff(frame.gray, before) > 40).astype(np.uint8)
        count, labels = cv2.connectedComponents(changed)
        return Decision(labels.astype(np.int32), np.arange(1, count, dtype=np.int32))

    def close(self) -> None:
        """Nothing to release."""


METHOD = FrameDifference
'''


def test_a_method_is_one_new_file_in_the_package(tmp_path, monkeypatch):
    import moseg_ros.methods as methods

    (tmp_path / "frame_difference.py").write_text(EXAMPLE_METHOD)
    monkeypatch.setattr(methods, "__path__", [*methods.__path__, str(tmp_path)])
    found = methods.discover(methods.__path__)
    assert set(found) == set(METHODS) | {"frame_difference"}
    decisions = method_contract(method_class("frame_difference", found), PipelineConfig())
    assert all(d.dynamic_ids.size > 0 for d in decisions[1:])  # the sliding block changes the pixels it crosses


class TestFrameInput:
    def test_gray_is_the_frame_itself_at_the_working_size(self):
        full = textured_frames(1)[0][..., 0].copy()
        assert FrameInput(full, full.shape).gray is full

    def test_gray_is_the_area_resized_frame_below_it(self):
        full = np.kron(np.arange(12, dtype=np.uint8).reshape(3, 4) * 10, np.ones((2, 2), np.uint8))
        gray = FrameInput(full, (3, 4)).gray
        assert gray.shape == (3, 4) and np.array_equal(gray, np.arange(12).reshape(3, 4) * 10)

    def test_the_default_method_never_resizes_to_the_working_size(self):
        method = method_class(DEFAULT_METHOD)(PipelineConfig())
        frames = [FrameInput(f[..., 0].copy(), (94, 310)) for f in textured_frames(3)]
        for frame in frames:
            method.step(frame)
        assert all("gray" not in vars(frame) for frame in frames)  # cached_property: never computed


def test_the_default_method_takes_upstream_instances_as_its_objects():
    pipeline = Pipeline(PipelineConfig(mask_margin_px=0))
    for i, frame in enumerate(textured_frames(6)):
        instances = np.zeros(frame.shape[:2], dtype=np.int32)
        y = 188 // 6 + 3 * i
        instances[y:y + 188 // 3, 621 // 4:621 // 4 + 621 // 8] = 7
        instances[150:, 500:] = 3
        result = pipeline.process(frame, i * 100_000_000, instances)
    assert result.dynamic_ids.tolist() == [7]
    assert (result.masks.instance_labels[instances == 7] == 7).all()


class TestPublishedRegions:
    def test_smoke_and_shape(self):
        labels = np.zeros((4, 6), dtype=np.int32)
        labels[1:3, 2:4] = 5
        regions = published_regions(labels, (8, 12), 0)
        assert regions.shape == (8, 12) and regions.dtype == bool

    def test_resized_without_margin_is_the_regions(self):
        labels = np.zeros((4, 6), dtype=np.int32)
        labels[1:3, 2:4] = 5
        expected = np.zeros((8, 12), dtype=bool)
        expected[2:6, 4:8] = True
        np.testing.assert_array_equal(published_regions(labels, (8, 12), 0), expected)

    def test_margin_grows_by_an_ellipse(self):
        labels = np.zeros((7, 7), dtype=np.int32)
        labels[3, 3] = 1
        grown = published_regions(labels, (7, 7), 1)
        expected = np.zeros((7, 7), dtype=bool)
        expected[2:5, 3] = expected[3, 2:5] = True  # OpenCV's 3x3 ellipse is a cross
        np.testing.assert_array_equal(grown, expected)


class TestHeldInstances:
    @staticmethod
    def scene(share_7: float, share_3: float) -> tuple[np.ndarray, np.ndarray]:
        """Two 10x10 instances (7 and 3) with the given share of their rows in the regions."""
        instances = np.zeros((10, 30), dtype=np.int32)
        instances[:, :10] = 7
        instances[:, 20:] = 3
        regions = np.zeros_like(instances, dtype=bool)
        regions[:round(10 * share_7), :10] = True
        regions[:round(10 * share_3), 20:] = True
        return instances, regions

    def test_an_instance_enters_at_the_min_fraction(self):
        instances, regions = self.scene(0.5, 0.3)
        assert held_instances(instances, regions, np.zeros(0, np.int32), 0.4, 0.1).tolist() == [7]

    def test_a_held_instance_stays_above_the_hold_fraction_and_a_new_one_does_not_enter(self):
        instances, regions = self.scene(0.2, 0.2)
        held = np.array([7], dtype=np.int32)
        assert held_instances(instances, regions, held, 0.4, 0.1).tolist() == [7]

    def test_a_held_instance_leaves_below_the_hold_fraction(self):
        instances, regions = self.scene(0.0, 0.5)
        assert held_instances(instances, regions, np.array([7], np.int32), 0.4, 0.1).tolist() == [3]

    def test_a_hold_at_the_min_fraction_holds_nothing(self):
        instances, regions = self.scene(0.2, 0.0)
        assert held_instances(instances, regions, np.array([7], np.int32), 0.4, 0.4).size == 0



class TestInstanceDecisions:
    @staticmethod
    def frame(id_left: int, id_right: int, share_left: float, share_right: float) -> tuple[np.ndarray, np.ndarray]:
        """Two 10x10 instances side by side with the given ids and shares of their rows in the regions."""
        instances = np.zeros((10, 30), dtype=np.int32)
        instances[:, :10], instances[:, 20:] = id_left, id_right
        regions = np.zeros_like(instances, dtype=bool)
        regions[:round(10 * share_left), :10] = True
        regions[:round(10 * share_right), 20:] = True
        return instances, regions

    def test_the_hold_follows_the_object_when_the_segmenter_renumbers_it(self):
        decisions = InstanceDecisions(0.4, 0.1)
        assert decisions.update(*self.frame(1, 2, 0.5, 0.0)).tolist() == [1]
        # The next frame the segmenter swaps the ids: the left object, now 2, keeps its flag; 1 is another object.
        assert decisions.update(*self.frame(2, 1, 0.2, 0.2)).tolist() == [2]

    def test_reset_forgets_the_flags(self):
        decisions = InstanceDecisions(0.4, 0.1)
        decisions.update(*self.frame(1, 2, 0.5, 0.0))
        decisions.reset()
        assert decisions.update(*self.frame(1, 2, 0.2, 0.0)).size == 0

    def test_negative_ids_are_no_instance(self):
        instances, regions = self.frame(-1, 4, 1.0, 1.0)
        assert InstanceDecisions(0.4, 0.1).update(instances, regions).tolist() == [4]


class TestWithUnknownRegions:
    @staticmethod
    def scene() -> tuple[np.ndarray, np.ndarray]:
        """A 10x30 map with instance 5 on the left third; region 2 lies on it, region 3 mostly beside it (a third of
        it on the instance), region 4 on the right third, on no instance."""
        instances = np.zeros((10, 30), dtype=np.int32)
        instances[:, :10] = 5
        labels = np.zeros_like(instances)
        labels[:5, :9] = 2
        labels[6:, 8:14] = 3
        labels[:, 22:] = 4
        return instances, labels

    def test_smoke_and_shape(self):
        combined, ids = with_unknown_regions(*self.scene())
        assert combined.shape == (10, 30) and combined.dtype == np.int32 and ids.dtype == np.int32

    def test_regions_mostly_outside_every_instance_are_painted_where_no_instance_is(self):
        instances, labels = self.scene()
        combined, ids = with_unknown_regions(instances, labels)
        assert ids.tolist() == [OWN_REGION_BASE + 3, OWN_REGION_BASE + 4]
        assert (combined[instances == 5] == 5).all()  # the instance keeps its pixels, region 3's third included
        assert (combined[(labels == 3) & (instances == 0)] == OWN_REGION_BASE + 3).all()
        assert (combined[labels == 4] == OWN_REGION_BASE + 4).all()
        assert not np.isin(combined, OWN_REGION_BASE + 2).any()  # region 2 lies on the instance: its decision

    def test_nothing_outside_leaves_the_instances_as_they_are(self):
        instances, labels = self.scene()
        combined, ids = with_unknown_regions(instances, np.where(labels == 2, 2, 0))
        assert ids.size == 0 and combined is instances

    def test_ids_start_above_a_segmenters_largest(self):
        instances, labels = self.scene()
        instances[instances == 5] = OWN_REGION_BASE + 100  # a segmenter's hashed ids
        _, ids = with_unknown_regions(instances, labels)
        assert ids.tolist() == [OWN_REGION_BASE + 104, OWN_REGION_BASE + 105]

    def test_ids_at_the_top_of_int32_leave_the_smallest_free_ids(self):
        instances, labels = self.scene()
        instances[instances == 5] = np.iinfo(np.int32).max
        instances[0, 15] = 1  # id 1 is taken
        combined, ids = with_unknown_regions(instances, labels)
        assert ids.tolist() == [2, 3] and (combined[labels == 4] == 3).all()

    def test_regions_at_another_size_are_resized(self):
        instances, labels = self.scene()
        small = labels[::2, ::2]  # (5, 15): each label keeps its place
        _, ids = with_unknown_regions(instances, small)
        assert ids.tolist() == [OWN_REGION_BASE + 3, OWN_REGION_BASE + 4]
