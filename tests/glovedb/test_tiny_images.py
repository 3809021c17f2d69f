"""Tiny images: exact labels, normalisation, rolls; icosphere views."""

import numpy as np
import pytest

from glovedb.rotations import geodesic_angle
from glovedb.tiny_images import (
    check_sizes,
    tiny_images,
    tiny_images_from_pixels,
    tiny_images_of_label_images,
)
from glovedb.views import HAND_CENTRE, database_views, icosphere


def blob_image(shape=(120, 160), offset=(30, 40), scale=1) -> np.ndarray:
    """A label image with three coloured rectangles (an L-shaped 'glove')."""
    image = np.zeros(shape, np.uint8)
    r, c = offset
    image[r : r + 40 * scale, c : c + 10 * scale] = 3
    image[r + 30 * scale : r + 40 * scale, c + 10 * scale : c + 30 * scale] = 7
    image[r : r + 10 * scale, c + 10 * scale : c + 20 * scale] = 10
    return image


def test_outputs_are_exact_labels_of_every_size():
    images = tiny_images(blob_image())
    assert sorted(images) == [8, 16, 32, 64]
    for size, image in images.items():
        assert image.shape == (size, size) and image.dtype == np.uint8
        assert set(np.unique(image)) <= {0, 3, 7, 10}
    # The 30 x 40 glove is centred in a 40 x 40 square of 64 cells: 8 empty columns,
    # then the 10-pixel-wide class-3 bar as 16 cells.
    np.testing.assert_array_equal(images[64][:, :8], 0)
    np.testing.assert_array_equal(images[64][:, 8:24], 3)
    np.testing.assert_array_equal(images[8][:, 1:3], 3)


def test_crop_is_invariant_to_position_and_scale():
    small = tiny_images(blob_image(offset=(10, 5)))
    moved = tiny_images(blob_image(offset=(60, 100)))
    large = tiny_images(blob_image(shape=(300, 300), offset=(20, 30), scale=3))
    for size in (8, 16, 32, 64):
        np.testing.assert_array_equal(small[size], moved[size])
        np.testing.assert_array_equal(small[size], large[size])


def test_aspect_ratio_is_preserved_and_content_centred():
    image = np.zeros((50, 50), np.uint8)
    image[10:30, 20:25] = 4  # 20 tall, 5 wide
    tiny = tiny_images(image, sizes=[16])[16]
    columns = np.flatnonzero(tiny.any(axis=0))
    assert tiny.any(axis=1).all()
    assert len(columns) == 4 and columns[0] == 6


def test_quarter_turn_roll_rotates_the_tiny_image():
    image = blob_image()
    rows, cols = np.nonzero(image)
    pixels = np.stack([cols, rows], axis=1).astype(float)
    turned = tiny_images_from_pixels(pixels, image[rows, cols], rolls_rad=[0.0, np.pi / 2])
    # A camera turned +90 degrees about +z sees the image turned 90 degrees clockwise.
    for size in (8, 16, 32, 64):
        np.testing.assert_array_equal(turned[size][1], np.rot90(turned[size][0], k=-1))


@pytest.mark.parametrize("sizes", [(8, 16, 32, 64), (8, 64), (4, 32)])
def test_label_images_path_equals_the_pixel_path(sizes):
    """The builder's batched path makes the same bytes as the pixels of each image."""
    images = np.stack(
        [blob_image(), blob_image(offset=(20, 70), scale=2), np.zeros((120, 160), np.uint8)]
    )
    images[0, 50:53, 100:140] = 1  # a thin bar: sub-pixel sampling at every size
    rolls = np.linspace(0.0, 2 * np.pi, 7, endpoint=False)
    batched = tiny_images_of_label_images(images, sizes, rolls_rad=rolls)
    assert sorted(batched) == sorted(sizes)
    for index, image in enumerate(images):
        rows, cols = np.nonzero(image)
        pixels = np.stack([cols, rows], axis=1).astype(float)
        single = tiny_images_from_pixels(pixels, image[rows, cols], sizes, rolls_rad=rolls)
        for size in sizes:
            assert batched[size].shape == (3 * 7, size, size)
            assert batched[size].dtype == np.uint8
            np.testing.assert_array_equal(batched[size][index * 7 : index * 7 + 7], single[size])
    assert not batched[sizes[0]][14:].any()
    with pytest.raises(ValueError, match=r"classes must be 0\.\.10"):
        tiny_images_of_label_images(np.full((1, 4, 4), 11, np.uint8))
    with pytest.raises(ValueError, match=r"classes must be 0\.\.10"):
        tiny_images_of_label_images(np.full((1, 4, 4), 257, np.uint16))
    with pytest.raises(TypeError, match="label_images"):
        tiny_images_of_label_images(np.zeros((1, 4, 4)))


def test_smaller_sizes_are_the_same_whichever_sizes_are_asked_for():
    image = blob_image(scale=2)
    every = tiny_images(image)
    for sizes in ([8, 64], [16], [32, 8]):
        some = tiny_images(image, sizes=sizes)
        for size in sizes:
            np.testing.assert_array_equal(some[size], every[size])


def test_empty_images_and_bad_input():
    empty = tiny_images(np.zeros((10, 10), np.uint8))
    assert all(not image.any() for image in empty.values())
    with pytest.raises(ValueError, match="powers of two"):
        check_sizes([8, 12])
    with pytest.raises(ValueError, match="label_image"):
        tiny_images(np.zeros((10, 10, 3), np.uint8))
    with pytest.raises(ValueError, match=r"classes 1\.\.10"):
        tiny_images_from_pixels([[0.0, 0.0]], [11])


@pytest.mark.parametrize(("subdivisions", "count"), [(0, 12), (1, 42), (2, 162)])
def test_icosphere_vertex_count_and_uniformity(subdivisions, count):
    vertices = icosphere(subdivisions)
    assert vertices.shape == (count, 3)
    np.testing.assert_allclose(np.linalg.norm(vertices, axis=1), 1.0, atol=1e-12)
    distances = np.linalg.norm(vertices[:, None] - vertices[None], axis=-1)
    np.fill_diagonal(distances, np.inf)
    nearest = distances.min(axis=1)
    # Nearly uniform: every vertex's nearest neighbour is about equally far.
    assert nearest.max() / nearest.min() < 1.25
    np.testing.assert_allclose(vertices.mean(axis=0), 0.0, atol=1e-12)


def test_database_views_are_positions_times_rolls():
    rotations, translations, rolls = database_views(1, 18)
    assert rotations.shape == (756, 3, 3) and translations.shape == (756, 3)
    np.testing.assert_allclose(rolls[1], np.radians(20))
    # Views of one position differ by their roll about the optical axis only.
    np.testing.assert_allclose(geodesic_angle(rotations[0], rotations[1]), np.radians(20))
    np.testing.assert_allclose(rotations[0][2], rotations[5][2], atol=1e-12)
    # Every camera looks at the middle of the hand from the same distance.
    centre = np.array(HAND_CENTRE) * 0.19
    np.testing.assert_allclose(rotations @ centre + translations, [[0, 0, 0.5]] * 756, atol=1e-12)
