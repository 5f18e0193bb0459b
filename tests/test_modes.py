"""Rank check: zero-energy modes of a free body of affine frames at the samples.

Oracles: rigid motions (translations, infinitesimal rotations) are in the null
space of K exactly (to round-off, 1e-12 relative to |K|); one mid-point sample
has rank 6 (its symmetric strain), so 12 n - 6 zero modes exactly; enough
samples leave exactly the 6 rigid modes.  Eigenvalues count as zero below
1e-8 of the largest (the spectrum gap measured here: rigid modes < 1e-15,
the smallest elastic ones > 1e-7).
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np
import pytest

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from sampling_standin import ShepardSF, frames_in, two_label_block  # noqa: E402

from voxflex.deform.modes import SpuriousModesWarning, check_modes, free_body_stiffness, zero_energy_modes  # noqa: E402
from voxflex.deform.nodes import skew  # noqa: E402
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
