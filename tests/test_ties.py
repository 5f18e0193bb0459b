"""Scale-free tie-breaking (voxflex._ties): values within 1e-9 of the extreme, relative to the largest
finite magnitude, tie and the lowest index wins, at any unit."""

import numpy as np
import pytest

from voxflex._ties import TIE, first_extreme, tie_key


@pytest.mark.parametrize("scale", [1e-6, 0.37, 1.0, 1e3])
def test_ties_are_broken_by_the_lowest_index_at_every_scale(scale):
    v = np.array([1.0, 3.0, 2.0, 3.0 * (1 + 1e-13), 0.5]) * scale
    assert first_extreme(v, "max") == 1  # 3 and 3(1 + 1e-13) tie
    w = np.array([2.0, 0.5 * (1 + 1e-13), 1.0, 0.5]) * scale
    assert first_extreme(w, "min") == 1
    assert first_extreme(np.array([1.0, 3.0, 2.0, 3.0 * (1 + 1e-6)]) * scale, "max") == 3  # a real gap


def test_infinities_compare_as_themselves_and_magnitudes_are_the_finite_ones():
    assert first_extreme(np.array([1.0, np.inf, 2.0, np.inf]), "max") == 1
    assert first_extreme(np.array([-1.0, 5.0, -np.inf, 5.0 * (1 + 1e-12)]), "max") == 1
    assert first_extreme(np.array([np.inf, 2.0, 1.0, 1.0 + 1e-12]), "min") == 2
    assert first_extreme(np.array([7.0]), "min") == 0


def test_tie_key_rounds_to_the_tie():
    a = tie_key(np.array([1.0, 1.0 + 0.1 * TIE, 2.0]), 1.0)
    assert a[0] == a[1] != a[2]
    assert np.array_equal(tie_key(np.array([0.37, 0.74]) ** 2, 0.37**2), tie_key(np.array([1.0, 4.0]), 1.0))


@pytest.mark.parametrize("scale", [1e-9, 1e-6, 1.0, 1e3])
def test_sentinels_below_the_floor_leave_the_tolerance_relative(scale):
    """Distances with -1 for excluded entries: with ``floor=0`` the sentinel is no magnitude, so the pick is
    the same at every unit (without it, the tolerance was TIE times max(best, 1): absolute below 1, and at
    1e-9 a 1e-3 relative gap counted as a tie)."""
    v = np.array([-1.0, 2.0 * (1 - 1e-3), -1.0, 2.0, 1.0]) * scale
    v[v < 0] = -1.0
    assert first_extreme(v, "max", floor=0.0) == 3  # a real gap at every scale
    t = np.array([-1.0, 2.0 * (1 - 1e-12), 2.0, 1.0]) * scale
    t[0] = -1.0
    assert first_extreme(t, "max", floor=0.0) == 1  # a tie at every scale
    w = np.array([5.0, 1.0 * (1 + 1e-3), 0.0, 1.0]) * scale
    w[2] = 1e300  # a sentinel above the floor for "min" (without it the whole array would tie)
    assert first_extreme(w, "min", floor=10.0 * scale) == 3
    assert first_extreme(w, "min") == 0


def test_the_samplers_farthest_points_are_the_same_at_every_unit():
    """The mid-point sampler's farthest points and Lloyd cells over part of a ball (the other voxels -1: the
    single-parent ones in a real scene) at 1 nm, 1 um, 0.37 m, 1 m and 1 km voxels: the same regions.  Before,
    the sentinel made the farthest points' tolerance absolute (the default scene's regions at 1 nm voxels
    differed in 3,580 of 3,736 voxels), and the graph in metres let voxels equidistant from two seeds go to
    either as the sums rounded at each scale (one voxel of this ball at 1 um); its distances are now in
    voxel units."""
    import dataclasses

    from voxflex.image.label_image import LabelImage
    from voxflex.sampling.sampler import _Context, _farthest_point_lloyd

    c = np.indices((16, 16, 16)).reshape(3, -1).T + 0.5 - 8.0
    labels = ((c**2).sum(1) <= 64.0).reshape(16, 16, 16).astype(np.uint8)  # a ball: many near-equal paths
    base = LabelImage(labels, spacing=(1.0, 1.0, 1.0))
    owners = []
    for s in (1e-9, 1e-6, 0.37, 1.0, 1e3):
        image = dataclasses.replace(base, spacing=np.asarray(base.spacing) * s, origin=np.zeros(3))
        ctx = _Context(image, image.labels > 0)
        cand = np.flatnonzero(ctx.graph.ijk[:, 0] >= 3)
        owners.append(_farthest_point_lloyd(ctx, cand, 40, 0, iterations=0))  # the farthest points alone
        owners.append(_farthest_point_lloyd(ctx, cand, 40, 0))  # and relaxed
    for k, o in enumerate(owners):
        assert np.array_equal(o, owners[6 + k % 2])  # those at 1 m
