"""Sampler regions, counts, determinism, fitted shape values and the geodesic kernel.

Oracles: partitions checked voxel by voxel; a quadratic weight field (exactly
reproduced by the quadratic fit, so w, dw, ddw at the sample equal the analytic
values to round-off: 1e-9 relative, the fit's normal equations have condition
~1e6); single-voxel regions give back the voxel's own values; the compiled
Dijkstra equals scipy's on the explicit graph (1e-12).
"""

from __future__ import annotations

import numpy as np
import pytest
from sampling_standin import QuadraticSF, ShepardSF, frames_in, two_label_block  # noqa: E402

from voxflex.errors import InputError  # noqa: E402
from voxflex.image import LabelImage  # noqa: E402
from voxflex.sampling import sample  # noqa: E402
from voxflex.sampling._geodesic import VoxelGraph  # noqa: E402


@pytest.fixture(scope="module")
def body():
    image = two_label_block(14, occupancy=True)
    frames = frames_in(image, 10) + 0.27 * image.spacing @ image.direction.T
    return image, ShepardSF(image, frames)


def _check_partition(image, s):
    mask = image.labels > 0
    reg = s.region
    assert np.all(reg[~mask] == -1)
    assert np.all(reg[mask] >= 0)
    assert np.array_equal(np.unique(reg[mask]), np.arange(s.m))
    # one label per region
    labs = image.labels[mask].astype(int)
    for lab in np.unique(labs):
        assert np.all(s.label[reg[mask][labs == lab]] == lab)
    occ = image.occupancy[mask] if image.occupancy is not None else np.ones(mask.sum())
    vol = np.bincount(reg[mask], weights=occ.astype(float), minlength=s.m) * image.voxel_volume
    assert np.allclose(vol, s.volume, rtol=1e-12, atol=0)


@pytest.mark.parametrize("kind", ["midpoint", "elaston"])
@pytest.mark.parametrize("count", [12, 40, 120])
def test_partition_and_count(body, kind, count):
    image, sf = body
    s = sample(image, sf, kind=kind, count=count)
    _check_partition(image, s)
    assert abs(s.m - count) <= 0.1 * count
    assert s.values.partition_of_unity_error() < 1e-10


@pytest.mark.parametrize("kind", ["midpoint", "elaston", "gauss-legendre"])
def test_deterministic(body, kind):
    image, sf = body
    a = sample(image, sf, kind=kind, count=30)
    b = sample(image, sf, kind=kind, count=30)
    assert np.array_equal(a.region, b.region) and np.array_equal(a.points, b.points)
    assert np.array_equal(a.values.w, b.values.w) and np.array_equal(a.values.index, b.values.index)


def test_single_parent_regions_are_voronoi_cells():
    """With one parent per voxel, mid-point regions are the (label, nearest frame) cells, one sample each."""
    image = two_label_block(12, rotated=False)
    frames = frames_in(image, 7) + 0.013
    s = sample(image, ShepardSF(image, frames, parents=1), kind="midpoint", count=200)
    mask = image.labels > 0
    x = image.voxel_centers()
    near = np.argmin(((x[:, None] - frames[None]) ** 2).sum(-1), axis=1)
    key = image.labels[mask].astype(int) * 100 + near
    _, expect = np.unique(key, return_inverse=True)
    got = s.region[mask]
    # same partition (up to numbering)
    assert len(np.unique(got)) == len(np.unique(expect)) == s.m
    pairs = np.unique(np.stack([got, expect.ravel()], 1), axis=0)
    assert len(pairs) == s.m


@pytest.mark.parametrize("kind", ["midpoint", "elaston"])
def test_fit_reproduces_a_quadratic_field(kind):
    image = two_label_block(10, occupancy=True)
    rng = np.random.default_rng(2)
    A = rng.normal(size=(3, 3))
    sf = QuadraticSF(image, 0.3, rng.normal(size=3), A + A.T)
    s = sample(image, sf, kind=kind, count=9)
    ref = sf(s.points)
    order = np.argsort(s.values.index, axis=1)  # parents 0, 1
    w = np.take_along_axis(s.values.w, order, 1)
    dw = np.take_along_axis(s.values.dw, order[..., None], 1)
    ddw = np.take_along_axis(s.values.ddw, order[..., None, None], 1)
    assert np.allclose(w, ref.w, rtol=0, atol=1e-9)
    assert np.allclose(dw, ref.dw, rtol=0, atol=1e-9 * np.abs(ref.dw).max())
    assert np.allclose(ddw, ref.ddw, rtol=0, atol=1e-9 * np.abs(ref.ddw).max())


def test_single_voxel_regions_return_voxel_values():
    lab = np.ones((3, 3, 2), np.uint8)
    image = LabelImage(lab, spacing=[0.1, 0.2, 0.15])
    frames = frames_in(image, 4) + 0.021
    sf = ShepardSF(image, frames)
    s = sample(image, sf, kind="elaston", count=18)
    assert s.m == 18
    vv = sf.voxel_values()
    v = s.region[lab > 0]  # sample of each voxel
    assert np.allclose(s.points[v], image.voxel_centers(), rtol=0, atol=1e-15)
    for c in range(len(v)):
        o1, o2 = np.argsort(vv.index[c]), np.argsort(s.values.index[v[c]])
        assert np.array_equal(vv.index[c][o1], s.values.index[v[c]][o2])
        assert np.allclose(vv.w[c][o1], s.values.w[v[c]][o2], rtol=0, atol=1e-12)
        assert np.allclose(vv.dw[c][o1], s.values.dw[v[c]][o2], rtol=0, atol=1e-10 * np.abs(vv.dw).max())
        assert np.allclose(vv.ddw[c][o1], s.values.ddw[v[c]][o2], rtol=0, atol=1e-10 * np.abs(vv.ddw).max())


def test_dijkstra_kernel_matches_scipy():
    rng = np.random.default_rng(0)
    mask = rng.random((9, 8, 7)) < 0.7
    g = VoxelGraph.from_mask(mask, [0.1, 0.2, 0.13])
    group = rng.integers(0, 2, g.n).astype(np.int64)
    seeds = np.sort(rng.choice(g.n, 5, replace=False))
    out = {}
    for backend in ("numba", "numpy"):
        dist = np.full(g.n, np.inf)
        owner = np.full(g.n, -1, dtype=np.int64)
        g.propagate(group, seeds[:3], np.arange(3), dist, owner, backend=backend)
        g.propagate(group, seeds[3:], np.arange(3, 5), dist, owner, backend=backend)  # incremental
        out[backend] = dist, owner
    d1, o1 = out["numba"]
    d2, o2 = out["numpy"]
    assert np.array_equal(np.isinf(d1), np.isinf(d2))
    fin = np.isfinite(d1)
    assert np.allclose(d1[fin], d2[fin], rtol=1e-12, atol=0)
    # owners: a nearest seed (ties allowed): its single-source distance equals the field
    for v in np.flatnonzero(fin):
        dd = np.full(g.n, np.inf)
        oo = np.full(g.n, -1, dtype=np.int64)
        g.propagate(group, seeds[o1[v]:o1[v] + 1], [0], dd, oo, backend="numba")
        assert dd[v] == pytest.approx(d1[v], rel=1e-12)


@pytest.mark.parametrize("shape, spacing", [((12, 6, 5), (1.0, 1.0, 1.0)), ((20, 15, 10), (0.5, 1.0, 2.0))])
def test_farthest_points_pick_the_seeds_of_full_scans(shape, spacing):
    """The compiled farthest-point search (block maxima, :func:`farthest_points`) against its definition: a
    loop that propagates each seed and takes the next as voxflex._ties.first_extreme of the whole field (-1:
    not a candidate).  Same seeds, distances and owners bit for bit, on a box full of exact ties and on a
    random body with anisotropic voxels (9 blocks of 256), two groups (each seed reaches only its own)."""
    from voxflex._ties import TIE, first_extreme
    from voxflex.sampling import _geodesic

    rng = np.random.default_rng(1)
    mask = np.ones(shape, dtype=bool) if shape[0] == 12 else rng.random(shape) < 0.7
    g = VoxelGraph.from_mask(mask, spacing)
    labels = rng.integers(1, 3, g.n).astype(np.int64)
    labels[rng.random(g.n) < 0.05] = -1  # not candidates
    cand = np.flatnonzero(labels >= 0)
    for k in (1, 7, len(cand) // 5, len(cand)):
        first = int(cand[rng.integers(len(cand))])
        dist = np.where(labels >= 0, np.inf, -1.0)
        owner = np.full(g.n, -1, dtype=np.int64)
        seeds = [first]
        g.propagate(labels, [first], [0], dist, owner)
        while True:
            v = first_extreme(dist, "max", floor=0.0)
            if dist[v] <= 0.0 or (len(seeds) >= k and np.isfinite(dist[v])):
                break
            seeds.append(v)
            g.propagate(labels, [v], [len(seeds) - 1], dist, owner)
        d2 = np.where(labels >= 0, np.inf, -1.0)
        o2 = np.full(g.n, -1, dtype=np.int64)
        s2 = _geodesic.farthest_points(g.lut, g.ijk, g.shape, g.steps, g.lengths, labels, d2, o2, first, k, TIE)
        assert np.array_equal(s2, seeds) and np.array_equal(d2, dist) and np.array_equal(o2, owner)
        assert len(seeds) >= min(k, len(cand)) and np.all(np.isfinite(dist[cand]))


def test_input_errors(body):
    image, sf = body
    with pytest.raises(InputError, match="did you mean 'elaston'"):
        sample(image, sf, kind="elastons")
    with pytest.raises(InputError, match="count"):
        sample(image, sf, count=0)
    with pytest.raises(InputError, match="LabelImage"):
        sample(np.ones((2, 2, 2)), sf)
    with pytest.raises(InputError, match="shape function"):
        sample(image, object())
    with pytest.raises(InputError, match="no material"):
        sample(LabelImage(np.zeros((2, 2, 2), np.uint8)), sf)
