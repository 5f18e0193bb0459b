"""Rank check: zero-energy modes of a free body of affine frames at the samples.

Oracles: rigid motions (translations, infinitesimal rotations) are in the null
space of K exactly (to round-off, 1e-12 relative to |K|); one mid-point sample
has rank 6 (its symmetric strain), so 12 n - 6 zero modes exactly; enough
samples leave exactly the 6 rigid modes.  Eigenvalues count as zero below
1e-8 of the largest (the spectrum gap measured here: rigid modes < 1e-15,
the smallest elastic ones > 1e-7).
"""

from __future__ import annotations

import numpy as np
import pytest
from sampling_standin import ShepardSF, frames_in, two_label_block  # noqa: E402

from voxflex.deform.chain.nodes import skew  # noqa: E402
from voxflex.deform.models.frames.modes import (
    SOFT_RATIO,
    SpuriousModesWarning,
    check_modes,
    free_body_stiffness,
    softest_mode,
    zero_energy_modes,
)
from voxflex.deform.models.frames.modes import _rigid_modes as rigid_basis
from voxflex.image import LabelImage  # noqa: E402
from voxflex.sampling import sample  # noqa: E402


@pytest.fixture(scope="module")
def body():
    image = two_label_block(12)
    # frames off the voxel centres, so that no voxel has a single Shepard parent
    frames = frames_in(image, 8) + 0.3 * image.spacing @ image.direction.T
    return image, frames, ShepardSF(image, frames)


def _rigid_modes(frames):
    n = len(frames)
    modes = []
    for a in range(3):
        q = np.zeros((n, 12))
        q[:, 9 + a] = 1.0
        modes.append(q.ravel())
        W = skew(np.eye(3)[a])
        q = np.zeros((n, 12))
        q[:, :9] = W.ravel()
        q[:, 9:] = frames @ W.T
        modes.append(q.ravel())
    return np.array(modes)


@pytest.mark.parametrize("kind,count", [("midpoint", 5), ("elaston", 5), ("gauss-legendre", 1)])
def test_rigid_motions_have_zero_energy(body, kind, count):
    image, frames, sf = body
    s = sample(image, sf, kind=kind, count=count)
    K = free_body_stiffness(frames, s)
    R = _rigid_modes(frames)
    assert np.abs(K @ R.T).max() <= 1e-12 * np.abs(K).max() * np.abs(R).max()
    assert np.allclose(K, K.T)


def test_one_sample_leaves_12n_minus_6_modes():
    lab = np.ones((4, 4, 4), np.uint8)
    image = LabelImage(lab, spacing=[0.1, 0.1, 0.1])
    frames = frames_in(image, 3) + 0.031
    s = sample(image, ShepardSF(image, frames), kind="midpoint", count=1)
    assert s.m == 1
    assert zero_energy_modes(frames, s) == 12 * 3 - 6


def test_too_few_midpoint_samples_detected(body):
    image, frames, sf = body
    s = sample(image, sf, kind="midpoint", count=5)
    assert s.m == 5
    with pytest.warns(SpuriousModesWarning, match=r"add at least \d+ samples"):
        zero = check_modes(frames, s)
    # rank <= 6 per sample: at least 12 n - 30 zero modes
    assert zero >= 12 * len(frames) - 6 * 5


@pytest.mark.parametrize("kind,count", [("midpoint", 60), ("gauss-legendre", 1), ("elaston", 8)])
def test_enough_samples_leave_exactly_six(body, kind, count):
    image, frames, sf = body
    s = sample(image, sf, kind=kind, count=count)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert check_modes(frames, s) == 6


def test_elaston_gradient_terms_add_rank(body):
    """8 elastons: 48 strain rows cannot control 96 - 6 modes without the gradient; with it they do."""
    image, frames, sf = body
    s = sample(image, sf, kind="elaston", count=8)
    assert zero_energy_modes(frames, s, gradient=False) >= 12 * 8 - 6 * 8
    assert zero_energy_modes(frames, s, gradient=True) == 6


def test_point_stiffness_kernel_equals_the_sparse_product(body):
    # the compiled pair-block path of free_body_stiffness against J^T blockdiag(V C) J assembled here
    # with the deformation-gradient mapping (round-off: 1e-12 of |K|)
    import scipy.sparse as sp

    from voxflex.deform.chain.mappings import DeformationGradientMapping
    from voxflex.deform.chain.nodes import AffineFrames
    from voxflex.deform.models.frames.modes import _unit_hooke_F

    image, frames, sf = body
    s = sample(image, sf, kind="midpoint", count=40)
    nodes = AffineFrames(frames)
    J = DeformationGradientMapping(nodes, s.values).jacobian(nodes.rest)
    H = sp.block_diag([v * _unit_hooke_F() for v in s.volume], format="csr")
    ref = (J.T @ H @ J).toarray()
    assert np.abs(free_body_stiffness(frames, s) - ref).max() <= 1e-12 * np.abs(ref).max()


def test_rigid_basis_is_orthonormal_and_spans_the_rigid_motions(body):
    _, frames, _ = body
    Q = rigid_basis(frames)
    R = _rigid_modes(frames)
    assert np.allclose(Q.T @ Q, np.eye(6), atol=1e-12)
    assert np.abs(R.T - Q @ (Q.T @ R.T)).max() <= 1e-12 * np.abs(R).max()  # R in span(Q)


def test_softest_mode_separates_sound_and_under_integrated_quadratures(body):
    # samples equal to the reference: every generalised eigenvalue is 1 (the rigid modes deflated to 1
    # too); one mid-point sample per voxel against 2x2x2 Gauss: a sound quadrature, ratio in (0.02, 1];
    # too few samples for the frames: a mode with (almost) no energy at the samples, ratio < SOFT_RATIO
    image, frames, sf = body
    every = sample(image, sf, kind="gauss-legendre", count=1)
    assert softest_mode(frames, every, every) == pytest.approx(1.0, rel=1e-8)
    from voxflex.sampling.voxel import voxel_samples

    mid = voxel_samples(image, sf, rule="midpoint")
    ratio = softest_mode(frames, mid, every)
    assert SOFT_RATIO < ratio <= 1.0 + 1e-9
    few = sample(image, sf, kind="midpoint", count=20)  # 20 x 6 strain rows for 90 modes: none exactly free
    assert check_modes(frames, few) == 6  # no exact zero mode: only the ratio tells
    assert softest_mode(frames, few, mid) < SOFT_RATIO
    # held DOFs: the ratio is the minimum of v^T K_s v / v^T K_ref v over the free DOFs, so holding more
    # (a subspace of the free set) can only raise it (Courant-Fischer; 1e-12 for round-off); the given
    # stiffness is used as is
    one = softest_mode(frames, few, mid, np.arange(12, 12 * len(frames)))  # frame 0 held
    two = softest_mode(frames, few, mid, np.arange(24, 12 * len(frames)))  # frames 0 and 1 held
    assert two >= one - 1e-12
    K = free_body_stiffness(frames, few)
    assert softest_mode(frames, few, mid, stiffness=K) == softest_mode(frames, few, mid)


def test_a_reference_singular_to_round_off_gives_no_verdict(monkeypatch):
    """softest_mode over held DOFs whose reference stiffness is singular only to round-off (three motionless motions
    at 1e-15 of the largest eigenvalue, the samples' stiffness along them round-off of either sign, as the
    phantom's clamped reproducing kernels gave): no verdict (None), where the generalised eigenproblem passed its
    factorisation and returned a negative ratio (-0.41 here, -58 on the phantom), which refused a sound scene as
    "1e+300 times softer"; a regular reference still gives its ratio."""
    from types import SimpleNamespace

    from voxflex.deform.models.frames import modes

    rng = np.random.default_rng(3)
    n = 2
    N = 12 * n
    Q, _ = np.linalg.qr(rng.standard_normal((N, N)))
    ev = np.linspace(1.0, 10.0, N)
    ev[:3] = [1e-15, 2e-15, 3e-15]  # positive to round-off: the factorisation of the reference passes
    Kr = (Q * ev) @ Q.T
    Kr = 0.5 * (Kr + Kr.T)
    evs = ev.copy()
    evs[:3] = [-5e-16, 2e-16, 1e-16]  # the samples' stiffness along them: round-off of either sign
    Ks = (Q * evs) @ Q.T
    Ks = 0.5 * (Ks + Ks.T)
    monkeypatch.setattr(modes, "free_body_stiffness", lambda frames, samples: Kr)
    frames = np.zeros((n, 3))
    dummy = SimpleNamespace(values=None)
    free = np.arange(N)
    assert modes.softest_mode(frames, dummy, dummy, free, stiffness=Ks) is None
    ev2 = ev.copy()
    ev2[:3] = [0.5, 0.6, 0.7]
    Kr2 = (Q * ev2) @ Q.T
    Kr2 = 0.5 * (Kr2 + Kr2.T)
    monkeypatch.setattr(modes, "free_body_stiffness", lambda frames, samples: Kr2)
    assert modes.softest_mode(frames, dummy, dummy, free, stiffness=0.5 * Kr2) == pytest.approx(0.5, rel=1e-10)
