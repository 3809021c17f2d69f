"""The glove pattern: 20 patches, 10 colors, each twice and far apart, every triangle painted."""

import numpy as np
import pytest

from glovedb.pattern import N_CLASSES, chroma_uv, face_labels, face_patches, load_pattern
from glovedb.resources import config_path


@pytest.fixture(scope="module")
def pattern():
    return load_pattern()


def test_every_color_on_exactly_two_patches(pattern):
    assert len(pattern.patches) == 20 and pattern.colors_rgb.shape == (10, 3)
    counts = np.bincount([p.label for p in pattern.patches], minlength=N_CLASSES + 1)
    np.testing.assert_array_equal(counts[1:], 2)
    tips = [p.label for p in pattern.patches if p.name.endswith("_tip")]
    assert len(set(tips)) == 5, "the five fingertips must have five different colors"


def test_every_triangle_gets_a_label_and_every_patch_is_used(hand_mesh, pattern):
    labels = face_labels(hand_mesh, pattern)
    assert labels.dtype == np.uint8 and labels.shape == (len(hand_mesh.faces),)
    assert labels.min() >= 1 and labels.max() <= 10
    patches = face_patches(hand_mesh, pattern)
    assert set(patches) == set(range(20))


def test_patches_of_one_color_are_far_apart(hand_mesh, pattern):
    patches = face_patches(hand_mesh, pattern)
    centroids = hand_mesh.rest_vertices_m[hand_mesh.faces].mean(axis=1)
    for label in range(1, N_CLASSES + 1):
        first, second = [i for i, p in enumerate(pattern.patches) if p.label == label]
        a, b = centroids[patches == first], centroids[patches == second]
        # Closest pair of triangles of the two patches, on the open hand.
        gap = np.min(np.linalg.norm(a[::7, None] - b[None, ::7], axis=-1))
        assert gap > 0.015, f"color {label}: patches only {gap * 1000:.0f} mm apart"


def test_colors_are_separated_in_lighting_robust_chroma(pattern):
    uv = chroma_uv(pattern.colors_rgb)
    distances = np.linalg.norm(uv[:, None] - uv[None], axis=-1)
    np.fill_diagonal(distances, np.inf)
    assert distances.min() > 0.3
    # Brightness changes do not move the chroma coordinates.
    np.testing.assert_allclose(chroma_uv(pattern.colors_rgb * 0.5), uv, atol=1e-9)


def test_palette_and_colorize(pattern):
    palette = pattern.palette()
    assert palette.shape == (11, 3) and palette.dtype == np.uint8
    np.testing.assert_array_equal(palette[0], 0)
    image = pattern.colorize(np.array([[0, 3]], np.uint8))
    np.testing.assert_array_equal(image[0, 1], pattern.colors_rgb[2])


def test_a_pattern_breaking_the_rules_is_rejected(tmp_path):
    text = config_path("glove/pattern.toml").read_text()
    broken = text.replace('name = "little_middle"\ncolor = 10', 'name = "little_middle"\ncolor = 9')
    path = tmp_path / "pattern.toml"
    path.write_text(broken)
    with pytest.raises(ValueError, match="exactly two"):
        load_pattern(path)
    path.write_text(text.replace('bones = ["ring_middle"]', 'bones = ["ring_knuckle"]'))
    with pytest.raises(ValueError, match="ring_knuckle"):
        load_pattern(path)
