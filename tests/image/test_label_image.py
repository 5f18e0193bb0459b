"""LabelImage statistics against hand-computed values.

The test image holds two labels on a 10 x 8 x 6 grid with anisotropic voxels
(0.5 x 0.25 x 0.125 m, voxel volume 1/64 m^3):

* label 1: the box [1:4, 2:5, 0:2] (18 voxels), plus voxel (0, 1, 0) touching
  the box's corner voxel (1, 2, 0) by an edge only, plus voxel (4, 5, 2)
  touching the box's corner voxel (3, 4, 1) by a vertex only: 20 voxels, one
  part with 26-connectivity, two with 18, three with 6;
* label 2: the box [5:9, 0:8, 3:6] (96 voxels) plus the far voxel (0, 7, 5):
  97 voxels in two parts for every connectivity.

All the numbers are dyadic, so every expected value is exact in float64 and
the comparisons are exact (tolerance 0) unless stated.
"""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.errors import InputError
from voxflex.image import LabelImage

SPACING = np.array([0.5, 0.25, 0.125])
ORIGIN = np.array([1.0, -2.0, 0.5])
VOXEL_VOLUME = 0.5 * 0.25 * 0.125  # 1/64 m^3


def two_boxes(**kwargs) -> LabelImage:
    labels = np.zeros((10, 8, 6), dtype=np.uint8)
    labels[1:4, 2:5, 0:2] = 1
    labels[0, 1, 0] = 1  # edge neighbour of (1, 2, 0)
    labels[4, 5, 2] = 1  # vertex neighbour of (3, 4, 1)
    labels[5:9, 0:8, 3:6] = 2
    labels[0, 7, 5] = 2
    return LabelImage(labels, spacing=SPACING, origin=ORIGIN, **kwargs)


def test_counts():
    image = two_boxes()
    assert image.label_counts() == {1: 20, 2: 97}
    assert image.label_counts(include_empty=True) == {0: 480 - 117, 1: 20, 2: 97}
    assert image.present_labels().tolist() == [1, 2]


def test_volumes_count_times_voxel_volume():
    volumes = two_boxes().label_volumes()
    assert volumes == {1: 20 * VOXEL_VOLUME, 2: 97 * VOXEL_VOLUME}  # 0.3125 and 1.515625 m^3, exact
    assert volumes[1] == 0.3125


def test_volumes_weighted_by_occupancy():
    occupancy = np.ones((10, 8, 6), dtype=np.float32)
    occupancy[5:9, 0:8, 3:6] = 0.5  # the big box of label 2 is half full
    volumes = two_boxes(occupancy=occupancy).label_volumes()
    assert volumes[1] == 20 * VOXEL_VOLUME
    assert volumes[2] == (96 * 0.5 + 1) * VOXEL_VOLUME  # 0.765625 m^3, exact in float32 and float64


def test_bounding_boxes_index_and_world():
    image = two_boxes()
    boxes = image.bounding_boxes()
    assert boxes[1][0].tolist() == [0, 1, 0] and boxes[1][1].tolist() == [5, 6, 3]
    assert boxes[2][0].tolist() == [0, 0, 3] and boxes[2][1].tolist() == [9, 8, 6]
    world = image.world_bounding_boxes()
    # label 1: corners origin + spacing * [0,1,0] and origin + spacing * [5,6,3]
    np.testing.assert_array_equal(world[1][0], [1.0, -1.75, 0.5])
    np.testing.assert_array_equal(world[1][1], [3.5, -0.5, 0.875])
    np.testing.assert_array_equal(world[2][0], [1.0, -2.0, 0.875])
    np.testing.assert_array_equal(world[2][1], [5.5, 0.0, 1.25])


def test_world_bounding_box_of_a_rotated_image():
    # 90 degrees about z: array axis i points along world +y, j along world -x
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    image = two_boxes(direction=rot)
    lo, hi = image.world_bounding_boxes()[1]
    # x = 1 - 0.25 j for j in [1, 6]; y = -2 + 0.5 i for i in [0, 5]; z = 0.5 + 0.125 k for k in [0, 3]
    np.testing.assert_allclose(lo, [-0.5, -2.0, 0.5], rtol=0, atol=1e-15)  # atol: one rounding of a product
    np.testing.assert_allclose(hi, [0.75, 0.5, 0.875], rtol=0, atol=1e-15)


@pytest.mark.parametrize(("connectivity", "parts_1"), [("vertex", 1), ("edge", 2), ("face", 3)])
def test_connected_components(connectivity, parts_1):
    image = two_boxes()
    assert image.component_counts(connectivity=connectivity) == {1: parts_1, 2: 2}
    components, n = image.connected_components(1, connectivity=connectivity)
    assert n == parts_1
    assert components.shape == image.shape
    assert np.count_nonzero(components) == 20
    # all material together: label 1's voxel (4,5,2) touches label 2's (5,5,3) by an edge, so
    # vertex: {box 1 + both extras + box 2}, {(0,7,5)}; edge: {box 1 + (0,1,0)}, {(4,5,2) + box 2},
    # {(0,7,5)}; face: the 3 + 2 parts of the labels alone
    _, n_all = image.connected_components(None, connectivity=connectivity)
    expected_all = {"vertex": 2, "edge": 3, "face": 5}[connectivity]
    assert n_all == expected_all


def test_unknown_connectivity_lists_choices():
    with pytest.raises(InputError, match="valid: edge, face, vertex"):
        two_boxes().connected_components(1, connectivity="corner")


def test_memory():
    assert two_boxes().nbytes == 480  # uint8 labels
    occupancy = np.zeros((10, 8, 6))
    assert two_boxes(occupancy=occupancy).nbytes == 480 + 480 * 4  # occupancy stored as float32
    wide = LabelImage(np.full((4, 4, 4), 300), spacing=1.0)
    assert wide.labels.dtype == np.uint16 and wide.nbytes == 128


def test_describe_and_repr():
    image = two_boxes()
    vertex = image.describe(connectivity="vertex")
    assert "10 x 8 x 6" in vertex
    assert "[0.5, 0.25, 0.125] m" in vertex
    assert "[1, -2, 0.5] m" in vertex
    assert "identity" in vertex
    lines = vertex.splitlines()
    row1 = next(line for line in lines if line.split()[:2] == ["1", "20"])
    row2 = next(line for line in lines if line.split()[:2] == ["2", "97"])
    assert row1.split()[2] == "0.3125" and row1.split()[4] == "1"  # volume, parts (vertex: label 1 is one part)
    assert row2.split()[2] == "1.51562" and row2.split()[4] == "2"
    # all material together by vertex (see test_connected_components): 116 voxels + (0,7,5)
    assert "components 2 (vertex connectivity" in vertex and "480 B" in vertex
    # face connectivity is the default: label 1 falls into 3 parts, the material into 5 components
    face = image.describe()
    assert face == image.describe(connectivity="face")
    row1 = next(line for line in face.splitlines() if line.split()[:2] == ["1", "20"])
    assert row1.split()[4] == "3"
    assert "components 5 (face connectivity" in face


def test_describe_lists_the_largest_components():
    image = two_boxes()
    text = image.describe(largest=2)
    # face components, largest first: box 2 without its stray voxel (96 voxels, label 2,
    # index box i 5..8, j 0..7, k 3..5), then box 1's block (18 voxels, label 1)
    big = next(line for line in text.splitlines() if line.split()[:2] == ["1", "96"])
    assert big.split()[2] == "2" and "[5, 0, 3] to [8, 7, 5]" in big
    second = next(line for line in text.splitlines() if line.split()[:2] == ["2", "18"])
    assert second.split()[2] == "1"
    assert "... and 3 smaller component(s) with 3 voxels in all" in text
    # the voxel counts of the listed components are brute-force counts of the component array
    components, n = image.connected_components(None, connectivity="face")
    assert sorted(np.bincount(components.ravel())[1:].tolist(), reverse=True) == [96, 18, 1, 1, 1]
    with pytest.raises(InputError, match="largest"):
        image.describe(largest=-1)
    short = repr(image)
    assert "\n" not in short and "10x8x6" in short and "labels=[1, 2]" in short


def test_describe_empty_image():
    image = LabelImage(np.zeros((2, 3, 4), dtype=np.uint8), spacing=0.1)
    text = image.describe()
    assert "none: all 24 voxels are 0 (empty); the image holds no material" in text
    assert "labels present" not in text and "component" not in text
    assert image.label_counts() == {} and image.label_volumes() == {} and image.bounding_boxes() == {}
