"""The heatmap network's training data: its settings, crop units and crop files."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fingertips.data import FingertipDataConfig
from fingertips.heatmap import CROP_PX, GRID, crop_cell_pixels, crop_units
from fingertips.heatmap_data import (
    Crops,
    heatmap_config_from_dict,
    load_crops,
    save_crops,
)


def _crops(n: int, seed: int) -> Crops:
    rng = np.random.default_rng(seed)
    tips = rng.uniform(-1, 1, (n, 5, 2)).astype(np.float32)
    tips[:, 2] = np.nan  # a hidden tip
    return Crops(
        rng.uniform(-1, 1, (n, CROP_PX, CROP_PX)).astype(np.float16),
        tips,
        rng.uniform(size=n) < 0.5,
    )


def test_crop_units_are_where_the_map_cells_project() -> None:
    centre = np.array([0.05, -0.02, 0.6])
    camera = np.array([500.0, 500.0, 320.0, 240.0])
    cells = np.array([[3.25, 17.5], [28.0, 0.0]])
    uv = crop_cell_pixels(cells, centre, camera)
    z = np.array([0.55, 0.7])  # any depth along the ray projects to the same crop unit
    points = np.stack(
        [(uv[:, 0] - camera[2]) * z / camera[0], (uv[:, 1] - camera[3]) * z / camera[1], z], 1
    )
    np.testing.assert_allclose((crop_units(points, centre) + 1) / 2 * GRID - 0.5, cells, atol=1e-9)


def test_config_reads_data_overrides_and_refuses_bad_values() -> None:
    config = heatmap_config_from_dict(
        {"crop_seeds": [4, 5], "width": 4, "data": {"curl_fraction": 0.3}}
    )
    assert config.crop_seeds == (4, 5)
    assert config.heatmap_data(FingertipDataConfig()).curl_fraction == 0.3
    with pytest.raises(ValueError, match="passes"):
        heatmap_config_from_dict({"passes": 3})
    with pytest.raises(ValueError, match="widht"):
        heatmap_config_from_dict({"widht": 4})
    with pytest.raises(ValueError, match="crop_centre"):
        heatmap_config_from_dict({"crop_centre": "palm"})
    assert heatmap_config_from_dict({"crop_centre": "fingers"}).crop_centre == "fingers"
    with pytest.raises(ValueError, match="curl_fracton"):
        heatmap_config_from_dict({"data": {"curl_fracton": 0.3}})
    with pytest.raises(ValueError, match="judge_leaf_nodes: expected at least 2"):
        heatmap_config_from_dict({"judge_leaf_nodes": 1})
    with pytest.raises(ValueError, match="judge_iterations"):
        heatmap_config_from_dict({"judge_iterations": 0})
    with pytest.raises(ValueError, match="judge_learning_rate: expected a positive rate"):
        heatmap_config_from_dict({"judge_learning_rate": 0.0})
    with pytest.raises(ValueError, match="verifier_learning_rate"):
        heatmap_config_from_dict({"verifier_learning_rate": -0.1})
    assert not heatmap_config_from_dict({"judge_candidates": False}).judge_candidates


def test_crop_files_round_trip_and_join_in_the_given_order(tmp_path: Path) -> None:
    data = FingertipDataConfig(curl_fraction=0.3)
    first, second = _crops(3, 0), _crops(2, 1)
    save_crops(first, tmp_path / "a.npz", data=replace(data, seed=5), seeds=[5])
    save_crops(second, tmp_path / "b.npz", data=replace(data, n_images=9), seeds=[6])
    joined = load_crops([tmp_path / "b.npz", tmp_path / "a.npz"], data=data)
    np.testing.assert_array_equal(joined.images, np.concatenate([second.images, first.images]))
    np.testing.assert_array_equal(joined.tips, np.concatenate([second.tips, first.tips]))
    np.testing.assert_array_equal(joined.whole_hand, [*second.whole_hand, *first.whole_hand])
    assert joined.images.dtype == np.float16 and joined.tips.dtype == np.float32
    assert not list(tmp_path.glob(".*.part"))  # written under a temporary name, renamed


def test_crop_files_of_other_settings_or_formats_are_refused(tmp_path: Path) -> None:
    save_crops(_crops(2, 0), tmp_path / "a.npz", data=FingertipDataConfig(), seeds=[1])
    with pytest.raises(ValueError, match=r"a\.npz: crops rendered with other .*curl_fraction"):
        load_crops([tmp_path / "a.npz"], data=FingertipDataConfig(curl_fraction=0.3))
    np.savez(tmp_path / "other.npz", images=np.zeros(3))
    with pytest.raises(ValueError, match=r"other\.npz: not a crop file"):
        load_crops([tmp_path / "other.npz"])
    with pytest.raises(ValueError, match=r"missing\.npz: cannot read crops"):
        load_crops([tmp_path / "missing.npz"])
    with pytest.raises(ValueError, match="at least one"):
        load_crops([])


def test_crops_of_another_centre_rule_are_refused(tmp_path: Path) -> None:
    data = FingertipDataConfig()
    save_crops(_crops(2, 0), tmp_path / "f.npz", data=data, seeds=[1], centre="fingers")
    save_crops(_crops(2, 1), tmp_path / "d.npz", data=data, seeds=[2])  # the default rule
    assert len(load_crops([tmp_path / "f.npz"], centre="fingers").images) == 2
    assert len(load_crops([tmp_path / "d.npz"], centre="density").images) == 2
    with pytest.raises(ValueError, match=r"f\.npz: crops centred by the 'fingers' rule"):
        load_crops([tmp_path / "d.npz", tmp_path / "f.npz"], centre="density")
