"""3x3 SVD by Jacobi rotations (voxflex.deform.materials._svd3): accuracy against numpy's LAPACK SVD and exact constructions.

Tolerances: the algorithm is backward stable with errors of a few ulps of |F|
(measured ~2e-15); the brief's targets are reconstruction and orthogonality
<= 1e-13 and singular values within 1e-12 of numpy's relative to the largest
one (LAPACK itself is only accurate to ~1e-16 |F| for the small ones), which
leaves ~50x margin for other CPUs / compilers while still catching any real
error (a wrong rotation or a missed sweep gives errors >= 1e-8).
"""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.deform.materials._svd3 import np_svd3, svd3
from voxflex.errors import InputError

REC_TOL = 1e-13  # |U diag(sig) V^T - F| / max|F|
ORTH_TOL = 1e-13  # |U^T U - I|, |V^T V - I|
SIG_TOL = 1e-12  # |sig - sig_numpy| / sig_1


def _rotations(rng, n):
    Q, _ = np.linalg.qr(rng.standard_normal((n, 3, 3)))
    return Q * np.sign(np.linalg.det(Q))[:, None, None]


def _with_singular_values(sig, n=200, seed=0):
    """R1 diag(sig) R2^T with random rotations R1, R2 (sig may carry a negative entry)."""
    rng = np.random.default_rng(seed)
    R1, R2 = _rotations(rng, n), _rotations(rng, n)
    return R1 @ (np.asarray(sig, dtype=float)[None, :, None] * np.swapaxes(R2, 1, 2))


def _families():
    rng = np.random.default_rng(42)
    return {
        "random": rng.standard_normal((500, 3, 3)),
        "near-identity": np.eye(3) + 0.2 * rng.standard_normal((500, 3, 3)),
        "tiny-strain": np.eye(3) + 1e-9 * rng.standard_normal((200, 3, 3)),
        "near-repeated-pair": _with_singular_values([1 + 1e-9, 1.0, 0.5]),
        "near-repeated-triple": _with_singular_values([1.0, 1 + 1e-12, 1 - 1e-12]),
        "flat": _with_singular_values([1.5, 1.0, 0.0]),
        "rank-1": _with_singular_values([2.0, 0.0, 0.0]),
        "graded": _with_singular_values([1.0, 1e-8, 1e-16]),
        "inverted": _with_singular_values([3.0, 2.0, -0.5]),
        "inverted-repeated": _with_singular_values([1.0, 1.0, -1.0]),
        "rotation": _with_singular_values([1.0, 1.0, 1.0]),
        "huge": 1e150 * rng.standard_normal((50, 3, 3)),
        "small": 1e-150 * rng.standard_normal((50, 3, 3)),
        "exact-flat": np.tile(np.diag([1.0, 2.0, 0.0]), (3, 1, 1)),
        "exact-rank-1": np.tile(np.outer([1.0, 2.0, 3.0], [0.0, 1.0, 1.0]), (3, 1, 1)),
        "zero": np.zeros((3, 3, 3)),
        "permutation": np.tile(np.eye(3)[[2, 0, 1]], (3, 1, 1)),
    }


FAMILIES = _families()


@pytest.mark.parametrize("signed", [False, True])
@pytest.mark.parametrize("family", list(FAMILIES))
def test_accuracy(family, signed):
    F = FAMILIES[family]
    U, sig, V = svd3(F, signed=signed)
    scale = np.maximum(np.abs(F).max(axis=(1, 2)), 1e-300)
    rec = U * sig[:, None, :] @ np.swapaxes(V, 1, 2) - F
    assert (np.abs(rec).max(axis=(1, 2)) / scale).max() <= REC_TOL
    for Q in (U, V):
        assert np.abs(np.swapaxes(Q, 1, 2) @ Q - np.eye(3)).max() <= ORTH_TOL
    ref = np.linalg.svd(F, compute_uv=False)
    assert (np.abs(np.abs(sig) - ref).max(axis=1) / scale).max() <= SIG_TOL * np.sqrt(3)  # sig_1 <= sqrt(3) max|F|
    # ordering: sig1 >= sig2 >= |sig3|
    assert np.all(sig[:, 0] >= sig[:, 1]) and np.all(sig[:, 1] >= np.abs(sig[:, 2]))
    # conventions: det V = +1 always; signed: det U = +1 and sig3 carries the sign of det F;
    # unsigned: all sig >= 0
    assert np.abs(np.linalg.det(V) - 1).max() <= ORTH_TOL
    if signed:
        assert np.abs(np.linalg.det(U) - 1).max() <= ORTH_TOL
        det = np.linalg.det(F / scale[:, None, None])  # scaled: no overflow for the 1e150 family
        clear = np.abs(det) > 1e-8  # sign of det F well defined
        assert np.all(np.sign(sig[clear, 2]) == np.sign(det[clear]))
    else:
        assert np.all(sig >= 0)


def test_singular_values_relative_when_well_conditioned():
    # away from rank deficiency each singular value agrees with numpy to 1e-12 of ITSELF
    F = _with_singular_values([5.0, 0.7, 0.01], seed=3)
    _, sig, _ = svd3(F)
    np.testing.assert_allclose(sig, np.tile([5.0, 0.7, 0.01], (F.shape[0], 1)), rtol=1e-12, atol=0)
    np.testing.assert_allclose(sig, np.linalg.svd(F, compute_uv=False), rtol=1e-12, atol=0)


def test_graded_small_singular_values_are_accurate():
    # one-sided Jacobi keeps tiny singular values accurate in absolute terms (~eps sig_1): a method
    # through C = F^T F would lose them below sqrt(eps) sig_1 ~ 1e-8
    F = _with_singular_values([1.0, 1e-6, 1e-10], seed=5)
    _, sig, _ = svd3(F)
    np.testing.assert_allclose(sig[:, 1], 1e-6, rtol=1e-8, atol=0)  # 1e-8 relative = 1e-14 absolute
    np.testing.assert_allclose(sig[:, 2], 1e-10, rtol=1e-4, atol=0)  # 1e-4 relative = 1e-14 absolute


def test_exact_cases():
    # diagonal input: sorted by |value|; signed moves the minus sign of det F into the last value
    U, sig, V = svd3(np.diag([1.0, 3.0, -2.0]), signed=True)
    np.testing.assert_array_equal(sig, [3.0, 2.0, -1.0])
    np.testing.assert_allclose(U @ np.diag(sig) @ V.T, np.diag([1.0, 3.0, -2.0]), rtol=0, atol=1e-15)
    _, sig, _ = svd3(np.diag([1.0, 3.0, -2.0]))
    np.testing.assert_array_equal(sig, [3.0, 2.0, 1.0])
    # a rotation: all singular values exactly 1 up to round-off, U V^T = F
    R = _with_singular_values([1.0, 1.0, 1.0], n=1, seed=9)[0]
    U, sig, V = svd3(R, signed=True)
    np.testing.assert_allclose(sig, 1.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(U @ V.T, R, rtol=0, atol=1e-15)
    # a reflection: the signed SVD gives (1, 1, -1), the ordinary one (1, 1, 1)
    np.testing.assert_allclose(svd3(-R, signed=True)[1], [1, 1, -1], rtol=0, atol=1e-15)
    np.testing.assert_allclose(svd3(-R)[1], [1, 1, 1], rtol=0, atol=1e-15)


def test_singular_vectors_match_numpy_when_unique():
    # well separated singular values: the singular vectors are unique up to a common sign per pair
    F = _with_singular_values([3.0, 2.0, 1.0], seed=11)
    U, sig, V = svd3(F)
    Un, sn, Vhn = np.linalg.svd(F)
    sgn = np.sign(np.einsum("nai,nai->ni", U, Un))
    # perturbation theory: vector error ~ eps |F| / gap = 1e-16 * 3 / 1
    np.testing.assert_allclose(U, Un * sgn[:, None, :], rtol=0, atol=1e-13)
    np.testing.assert_allclose(V, np.swapaxes(Vhn, 1, 2) * sgn[:, None, :], rtol=0, atol=1e-13)


@pytest.mark.parametrize("signed", [False, True])
def test_numpy_twin_matches_kernel(signed):
    # same algorithm, different rounding order: unique decompositions (gap >= 0.3) agree to ~eps/gap
    F = np.concatenate([_with_singular_values([2.0, 1.0, 0.3], seed=1),
                        _with_singular_values([2.0, 1.0, -0.3], seed=2),
                        np.zeros((1, 3, 3))])
    for a, b in zip(svd3(F, signed=signed), np_svd3(F, signed)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


def test_validation():
    with pytest.raises(InputError, match="shape"):
        svd3(np.eye(2))
    with pytest.raises(InputError, match="finite"):
        svd3(np.full((3, 3), np.inf))
    U, sig, V = svd3(np.eye(3))
    assert U.shape == (3, 3) and sig.shape == (3,) and V.shape == (3, 3)
