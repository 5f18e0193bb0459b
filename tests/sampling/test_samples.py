"""Samples and their volume moments: exact against brute-force sub-voxel integration.

Oracle: every voxel is cut into 2x2x2 sub-cubes, each integrated with the
3-point tensor Gauss-Legendre rule (exact for degree 5 per axis, and the
moments have degree <= 4), evaluated directly in world coordinates through
``LabelImage.index_to_world`` -- independent of the shift-table algebra of
``voxflex.sampling.volume_moments``.  Agreement is therefore to round-off: the
tolerance is 1e-11 relative to the scale V * L^|alpha| of each moment
(L the object's extent).
"""

from __future__ import annotations

import numpy as np
import pytest
from sampling_standin import ShepardSF, frames_in, two_label_block  # noqa: E402

from voxflex.deform.materials.elaston import elaston_energy  # noqa: E402
from voxflex.deform.materials.laws import HookeLaw, isotropic_stiffness  # noqa: E402
from voxflex.errors import InputError  # noqa: E402
from voxflex.sampling import Samples, sample  # noqa: E402
from voxflex.sampling.quadrature import gauss_legendre_cube  # noqa: E402
from voxflex.sampling.volume_moments import (
    EXPONENT_INDEX,
    EXPONENTS,
    box_moment_table,
    monomials,
)


def _subcell_rule():
    """Local points (216, 3) in [0, 1]^3 and weights summing to 1: 2x2x2 sub-cubes x 3-point Gauss."""
    q, w = gauss_legendre_cube(3)
    pts, wts = [], []
    for corner in np.ndindex(2, 2, 2):
        pts.append((np.array(corner) + q) / 2.0)
        wts.append(w / 8.0)
    return np.concatenate(pts), np.concatenate(wts)


def brute_moments(image, cells_ijk, cell_lo, cell_size, occ, owner, points):
    """int over cells (voxel-index boxes [lo, lo + size]) of (x - p_owner)^alpha, density occ."""
    q, w = _subcell_rule()
    out = np.zeros((len(points), len(EXPONENTS)))
    vol = image.voxel_volume * float(cell_size) ** 3
    occ = np.asarray(occ, dtype=np.float64)
    for c in range(len(cells_ijk)):
        x = image.index_to_world(cells_ijk[c] + cell_lo[c] + q * cell_size)
        out[owner[c]] += occ[c] * vol * (w @ monomials(x - points[owner[c]]))
    return out


def _scale(image, volume):
    L = float(np.ptp(image.voxel_centers(), axis=0).max())
    return volume * L ** EXPONENTS.sum(1)


@pytest.fixture(scope="module")
def block():
    image = two_label_block(10, occupancy=True)
    return image, ShepardSF(image, frames_in(image, 6))


def test_box_table_analytic():
    """A unit-density box: V, second moments l^2 V / 12, fourth l^4 V / 80 and l_a^2 l_b^2 V / 144 (analytic)."""
    size = np.array([1.0, 2.0, 3.0])
    t = box_moment_table(size, np.eye(3))
    V = 6.0
    assert t[0] == pytest.approx(V, rel=1e-14)
    for a in range(3):
        e2 = [0, 0, 0]
        e2[a] = 2
        e4 = [0, 0, 0]
        e4[a] = 4
        assert t[EXPONENT_INDEX[tuple(e2)]] == pytest.approx(V * size[a] ** 2 / 12, rel=1e-13)
        assert t[EXPONENT_INDEX[tuple(e4)]] == pytest.approx(V * size[a] ** 4 / 80, rel=1e-13)
    assert t[EXPONENT_INDEX[(2, 2, 0)]] == pytest.approx(V * 4.0 / 144, rel=1e-13)
    odd = EXPONENTS.sum(1) % 2 == 1
    assert np.abs(t[odd]).max() < 1e-14


@pytest.mark.parametrize("kind", ["midpoint", "elaston"])
def test_region_moments_match_brute_force(block, kind):
    image, sf = block
    s = sample(image, sf, kind=kind, count=12)
    ijk = np.argwhere(image.labels > 0)
    owner = s.region[image.labels > 0]
    occ = image.occupancy[image.labels > 0]
    ref = brute_moments(image, ijk, np.zeros((len(ijk), 3)), 1.0, occ, owner, s.points)
    scale = _scale(image, s.volume.sum())
    assert np.all(np.abs(s.moments - ref) <= 1e-11 * scale)
    assert np.array_equal(s.moments[:, 0], s.volume)
    # points are the centroids: first moments vanish (to round-off)
    assert np.abs(s.M1).max() <= 1e-11 * scale[1]
    i = EXPONENT_INDEX
    assert np.allclose(s.M2[:, 0, 1], s.moments[:, i[(1, 1, 0)]]) and np.allclose(s.M2[:, 2, 2], s.moments[:, i[(0, 0, 2)]])


def test_gauss_octant_moments_match_brute_force(block):
    image, sf = block
    s = sample(image, sf, kind="gauss-legendre")
    ijk = np.argwhere(image.labels > 0)
    q, _ = gauss_legendre_cube(2)
    lo = np.floor(q * 2) / 2  # octant of each Gauss point
    cells = np.repeat(ijk, 8, axis=0)
    cell_lo = np.tile(lo, (len(ijk), 1))
    occ = np.repeat(image.occupancy[image.labels > 0], 8)
    ref = brute_moments(image, cells, cell_lo, 0.5, occ, np.arange(len(cells)), s.points)
    assert np.all(np.abs(s.moments - ref) <= 1e-11 * _scale(image, s.volume.sum()))
    assert np.allclose(s.points, image.index_to_world(cells + np.tile(q, (len(ijk), 1))), rtol=0, atol=1e-15)
    # region image: first sample of each voxel; values straight from sf
    assert np.array_equal(s.region[image.labels > 0], 8 * np.arange(len(ijk)))
    np.testing.assert_array_equal(s.values.w, sf(s.points).w)


@pytest.mark.parametrize("occupancy", [False, True])
@pytest.mark.parametrize("kind", ["midpoint", "elaston", "gauss-legendre"])
def test_volumes_sum_to_object(kind, occupancy):
    """Round-off: relative 1e-13 (sums of ~1e3 positive terms)."""
    image = two_label_block(12, occupancy=occupancy, rotated=False)
    sf = ShepardSF(image, frames_in(image, 8))
    s = sample(image, sf, kind=kind, count=30)
    total = sum(image.label_volumes().values())
    assert s.volume.sum() == pytest.approx(total, rel=1e-13)
    for lab, v in image.label_volumes().items():
        assert s.volume[s.label == lab].sum() == pytest.approx(v, rel=1e-13)


def test_elaston_quadratic_energy_exact_against_gauss():
    """Hooke energy of a linearly varying strain: elastons (V, M1, M2) == Gauss 2x2x2 per voxel to 1e-10.

    Both are exact for a quadratic integrand per voxel / region, so they agree to round-off
    (the 1e-10 bound of the issue; measured ~1e-15).
    """
    image = two_label_block(12, occupancy=True)
    sf = ShepardSF(image, frames_in(image, 8))
    rng = np.random.default_rng(3)
    e_ref, G = rng.normal(size=6) * 1e-2, rng.normal(size=(6, 3))
    x_ref = image.voxel_centers().mean(0)
    law = HookeLaw(isotropic_stiffness(1.3, 0.7))

    def strain(x):
        return e_ref + (x - x_ref) @ G.T

    gauss = sample(image, sf, kind="gauss-legendre")
    E_gauss = float((gauss.volume * law.energy(strain(gauss.points))).sum())
    for kind, count in (("elaston", 25), ("midpoint", 25), ("elaston", 3)):
        s = sample(image, sf, kind=kind, count=count)
        Gs = np.broadcast_to(G, (s.m, 6, 3))
        E = elaston_energy(law, strain(s.points), Gs, s.volume, s.M1, s.M2, hessian=False).energy.sum()
        assert E == pytest.approx(E_gauss, rel=1e-10)
    # and the point (mid-point) rule alone is not exact: the check has teeth
    E_mid = float((s.volume * law.energy(strain(s.points))).sum())
    assert abs(E_mid - E_gauss) > 1e-6 * E_gauss


def test_samples_container_validation(block):
    image, sf = block
    s = sample(image, sf, kind="midpoint", count=8)
    assert isinstance(s, Samples) and s.m == len(s.points) and s.n_frames == 6
    assert not s.points.flags.writeable
    with pytest.raises(InputError, match="volume"):
        Samples(s.kind, s.points, -s.volume, s.moments, s.label, s.region, s.values)
    with pytest.raises(InputError, match="moments"):
        Samples(s.kind, s.points, s.volume, s.moments[:, :10], s.label, s.region, s.values)
