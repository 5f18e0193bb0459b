"""Sampler regions, counts, determinism, fitted shape values and the geodesic kernel.

Oracles: partitions checked voxel by voxel; a quadratic weight field (exactly
reproduced by the quadratic fit, so w, dw, ddw at the sample equal the analytic
values to round-off: 1e-9 relative, the fit's normal equations have condition
~1e6); single-voxel regions give back the voxel's own values; the sampler's
cells come from the Dijkstra that ``geodesic_distance(method="dijkstra")`` runs,
with the same distances (the kernel's own oracles are in
``tests/voronoi/test_geodesic.py``).
"""

from __future__ import annotations

import numpy as np
import pytest
from sampling_standin import QuadraticSF, ShepardSF, frames_in, two_label_block  # noqa: E402

from voxflex.errors import InputError  # noqa: E402
from voxflex.image import LabelImage  # noqa: E402
from voxflex.sampling import sample  # noqa: E402


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


def test_the_sampler_and_geodesic_distance_run_one_dijkstra(monkeypatch):
    """The sampler's cells and ``geodesic_distance(method="dijkstra")`` both run the march's Dijkstra
    (:func:`voxflex.voronoi._march._march`, order 0; recorded by a wrapper) and give the same distances, bit
    for bit, on an L-shaped body of anisotropic voxels whose smallest edge is 1 (the sampler's voxel units
    are then the image's) from seeds at voxel centres (the march's seeds at distance 0)."""
    from voxflex.sampling.sampler import _Context
    from voxflex.voronoi import _march as M
    from voxflex.voronoi import geodesic_distance

    calls = []
    kernel = M._march

    def recording(*args):
        calls.append(args[13])  # fmm: 0 is Dijkstra
        return kernel(*args)

    monkeypatch.setattr(M, "_march", recording)
    labels = np.zeros((9, 8, 5), np.uint8)
    labels[:3] = labels[:, :3] = 1
    image = LabelImage(labels, spacing=(1.0, 1.5, 1.25))
    ctx = _Context(image, labels > 0)
    g = ctx.graph
    seeds = np.array([0, ctx.n // 2, ctx.n - 1])
    dist = g.field(np.inf)
    owner = g.field(-1, dtype=np.int64)
    g.propagate(g.field(0, dtype=np.int64), seeds, np.arange(3), dist, owner)
    d, own = geodesic_distance(image, ctx.centres[seeds], method="dijkstra")
    assert calls == [0, 0]
    assert np.array_equal(dist[g.flat], d[labels > 0]) and np.all(np.isfinite(d[labels > 0]))
    assert np.array_equal(owner[g.flat], own[labels > 0])  # the same owners here (no exact tie between seeds)


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
