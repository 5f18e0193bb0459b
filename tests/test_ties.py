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
