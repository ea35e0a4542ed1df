"""A user's TorchScript instance model as the instance source: conventions, stable ids, and the decision."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import textured_frames
from moseg_ros.frontend.torch_instances import TorchScriptInstances, masks_to_ids
from moseg_ros.pipeline import Pipeline, PipelineConfig

torch = pytest.importorskip("torch", reason="torch (requirements.txt) is not installed")

HEIGHT, WIDTH = 188, 621


class BoxesModel(torch.nn.Module):
    """Per-instance scores (1, 2, H, W): box 0 covers the sliding block's path, box 1 a static patch. It also
    reads the image, so a model that ignores its input is not what is tested."""

    def __init__(self) -> None:
        super().__init__()
        masks = torch.zeros(2, HEIGHT, WIDTH)
        masks[0, HEIGHT // 6:HEIGHT // 6 + HEIGHT // 3 + 18, WIDTH // 4:WIDTH // 4 + WIDTH // 8] = 1.0
        masks[1, 130:180, 450:600] = 1.0
        self.register_buffer("masks", masks)

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        assert image.dim() == 4 and image.shape[1] == 3
        return (self.masks * (image.mean() >= 0.0).float())[None]


@pytest.fixture
def model_path(tmp_path):
    path = tmp_path / "boxes.pt"
    torch.jit.script(BoxesModel()).save(str(path))
    return path


class TestMasksToIds:
    def test_id_maps_pass_and_masks_take_their_best_instance(self):
        ids = np.array([[0, 3], [3, 5]], dtype=np.int64)
        assert masks_to_ids(ids).tolist() == ids.tolist()
        assert masks_to_ids(ids[None]).tolist() == ids.tolist()
        scores = np.array([[[0.9, 0.2], [0.6, 0.1]], [[0.1, 0.7], [0.8, 0.3]]], dtype=np.float32)
        assert masks_to_ids(scores).tolist() == [[1, 2], [2, 0]]
        assert masks_to_ids(scores[None]).tolist() == [[1, 2], [2, 0]]

    def test_no_instances_and_bad_shapes(self):
        assert not masks_to_ids(np.zeros((0, 4, 5), np.float32)).any()
        with pytest.raises(ValueError, match="instance model output"):
            masks_to_ids(np.zeros((4,), np.float32))


class TestTorchScriptInstances:
    def test_ids_are_stable_over_frames(self, model_path):
        source = TorchScriptInstances(model_path)
        maps = [source(frame) for frame in textured_frames(3)]
        assert maps[0].shape == (HEIGHT, WIDTH) and maps[0].dtype == np.int32
        assert len(np.unique(maps[0])) == 3 and all(np.array_equal(maps[0], m) for m in maps[1:])
        assert str(source.device) in ("cpu", "cuda")

    def test_a_missing_file_is_a_clear_error(self, tmp_path):
        with pytest.raises(ValueError, match="is not a file"):
            TorchScriptInstances(tmp_path / "none.pt")


def test_the_pipeline_flags_the_model_instance_that_moves_and_not_the_static_one(model_path):
    pipeline = Pipeline(PipelineConfig(instance_model=str(model_path), mask_margin_px=0))
    for i, frame in enumerate(textured_frames(6)):
        result = pipeline.process(frame, i * 100_000_000)
    labels = result.masks.instance_labels
    assert result.dynamic_ids.size == 1
    assert (labels[HEIGHT // 6 + 20, WIDTH // 4 + 10] == result.dynamic_ids[0])
    assert not labels[130:180, 450:600].any()
