"""Chord steps of Newton with dense tangents (``chord.CHORD_RATE``, ``chord._Chord``).

A frame model's Hessian costs far more than its gradient (its pair blocks: 432 P^2 flops per sample), so a
load or time step solves with an earlier iteration's factorised Hessian while that contracts the residual
by CHORD_RATE per step.  The iterates change, the answer must not beyond what the residual test allows:
every state equals full Newton's to 1e-6 of the largest displacement (the Newton tolerance is 1e-8 of the
forces), with fewer Hessians.
"""

from __future__ import annotations

import numpy as np
from robust import beam

import voxflex as vf
from voxflex.deform.solve import chord as _chord
from voxflex.deform.solve import stepping
from voxflex.scene import Scene


class _NoChord(_chord._Chord):
    def ready(self, n):
        return False


def _run(monkeypatch, chord: bool, dynamic: bool = True):
    text = beam("affine", model="neo-hookean", young="2.0e3", density="100.0",
                nodes='count = 8\nshape_function = "reproducing-kernel"', elasticity='quadrature = "elaston"',
                solver="" if dynamic else "steps = 4")
    if dynamic:
        text = text.replace('kind = "static"', 'kind = "implicit-euler"\ndt = 0.02\nsteps = 8')
    if not chord:
        monkeypatch.setattr(stepping, "_Chord", _NoChord)
    model = vf.model(Scene.from_toml_text(text), cache=False)
    calls = {"hessians": 0}

    def counting(inner):
        def counted(q, *, gradient=True, hessian=True):
            calls["hessians"] += bool(gradient and hessian)
            return inner(q, gradient=gradient, hessian=hessian)
        return counted

    # the solvers evaluate the frames at their displacement (FromDisplacement); other callers at positions
    for name in ("energy_gradient_hessian", "energy_gradient_hessian_u"):
        monkeypatch.setattr(model, name, counting(getattr(model, name)))
    r = vf.simulate(Scene.from_toml_text(text), model=model, progress=False)
    monkeypatch.undo()
    return r, calls["hessians"]


def test_chord_steps_give_full_newtons_trajectory_with_fewer_hessians(monkeypatch):
    full, h_full = _run(monkeypatch, chord=False)
    fast, h_fast = _run(monkeypatch, chord=True)
    u_full = full.surface_positions - full.surface_rest
    u_fast = fast.surface_positions - fast.surface_rest
    scale = np.abs(u_full).max()
    assert scale > 1e-2  # it moved (a soft beam swinging under gravity)
    np.testing.assert_allclose(u_fast, u_full, rtol=0, atol=1e-6 * scale)
    assert h_fast < h_full, (h_fast, h_full)


def test_chord_steps_give_full_newtons_static_answer_with_fewer_hessians(monkeypatch):
    """Load steps share the chord too (a large sag: 4 steps of a soft neo-Hookean cantilever)."""
    full, h_full = _run(monkeypatch, chord=False, dynamic=False)
    fast, h_fast = _run(monkeypatch, chord=True, dynamic=False)
    u_full = full.surface_positions - full.surface_rest
    scale = np.abs(u_full).max()
    assert scale > 0.1
    np.testing.assert_allclose(fast.surface_positions - fast.surface_rest, u_full, rtol=0, atol=1e-6 * scale)
    assert h_fast < h_full, (h_fast, h_full)


def test_an_indefinite_tangent_is_never_kept():
    """cho_factor refuses it: no chord steps with it (Newton's own remedies handle the iterate)."""
    c = _chord._Chord()
    c.store(np.diag([1.0, -1.0]), np.ones(2))
    assert not c.ready(2)
    c.store(np.diag([2.0, 4.0]), np.ones(2))
    assert c.ready(2) and c.good
    np.testing.assert_allclose(c.solve(np.array([2.0, 4.0])), [1.0, 1.0])


def test_the_secants_correct_the_kept_factor():
    """Limited-memory BFGS on top of the factor: after a pair (s, y) the chord maps y to s (the secant
    equation), stays symmetric positive definite, and a pair of non-positive curvature is refused."""
    rng = np.random.default_rng(3)
    n = 6
    B = rng.normal(size=(n, n))
    H0 = B @ B.T + n * np.eye(n)  # the kept (old) tangent
    Ht = H0 + np.diag(np.linspace(0.0, 5.0, n))  # the true tangent has moved on
    c = _chord._Chord()
    c.store(H0, np.ones(n))
    for _ in range(3):
        s = rng.normal(size=n)
        assert c.secant(s, Ht @ s)
        np.testing.assert_allclose(c.solve(Ht @ s), s, rtol=1e-12, atol=1e-12)
    Hinv = np.column_stack([c.solve(e) for e in np.eye(n)])
    np.testing.assert_allclose(Hinv, Hinv.T, rtol=0, atol=1e-12 * np.abs(Hinv).max())
    assert np.linalg.eigvalsh(0.5 * (Hinv + Hinv.T)).min() > 0
    kept = list(c.pairs)
    assert not c.secant(np.ones(n), -np.ones(n))  # y . s < 0: negative curvature, nothing kept
    assert c.pairs == kept
    assert len(c.pairs) <= _chord.CHORD_MEMORY
    c.store(H0, np.ones(n))  # a fresh tangent forgets the secants
    assert c.pairs == []


def test_the_extrapolated_start_leaves_the_trajectory_as_it_was(monkeypatch):
    """Newton starts a step from u + h (2 v - v_prev): the states equal those from the inertial prediction
    u + h v to 1e-6 of the largest displacement (the residual test's reach), in fewer model passes."""
    def run(predictor):
        monkeypatch.setattr(stepping, "PREDICTOR", predictor)
        text = beam("affine", model="neo-hookean", young="2.0e3", density="100.0",
                    nodes='count = 8\nshape_function = "reproducing-kernel"', elasticity='quadrature = "elaston"',
                    solver="").replace('kind = "static"', 'kind = "implicit-euler"\ndt = 0.02\nsteps = 8')
        model = vf.model(Scene.from_toml_text(text), cache=False)
        passes = {"n": 0}
        inner = model.energy_gradient_hessian

        def counted(q, *, gradient=True, hessian=True):
            passes["n"] += 1
            return inner(q, gradient=gradient, hessian=hessian)

        monkeypatch.setattr(model, "energy_gradient_hessian", counted)
        r = vf.simulate(Scene.from_toml_text(text), model=model, progress=False)
        return r.surface_positions - r.surface_rest, passes["n"]

    u_plain, n_plain = run(False)
    u_extra, n_extra = run(True)
    scale = np.abs(u_plain).max()
    assert scale > 1e-2
    np.testing.assert_allclose(u_extra, u_plain, rtol=0, atol=1e-6 * scale)
    assert n_extra <= n_plain, (n_extra, n_plain)


def test_a_factor_serving_many_solves_becomes_its_inverse(monkeypatch):
    """After CHORD_INVERSE_AFTER solves a kept factor solves by its explicit inverse (made once): the same
    steps as the triangular solves to round-off (1e-12 relative; cond(H) ~ 10 here, so eps cond ~ 1e-15), with
    and without secant pairs; a matrix above CHORD_INVERSE_MAX keeps the triangular solves."""
    rng = np.random.default_rng(3)
    n = 40
    B = rng.standard_normal((n, n))
    H = B @ B.T + n * np.eye(n)
    chord = _chord._Chord()
    chord.store(H, np.diag(H))
    rhs = [rng.standard_normal(n) for _ in range(2 * _chord.CHORD_INVERSE_AFTER)]
    inverses = set()
    for k, b in enumerate(rhs):
        if k == 3:
            s = rng.standard_normal(n)
            assert chord.secant(s, H @ s)  # an exact secant pair: the L-BFGS correction leaves H's solve alone
        z = chord.solve(b)
        assert np.linalg.norm(z - np.linalg.solve(H, b)) <= 1e-12 * np.linalg.norm(z)
        assert (chord.inverse is not None) == (k + 1 >= _chord.CHORD_INVERSE_AFTER)
        if chord.inverse is not None:
            inverses.add(id(chord.inverse))
    assert len(inverses) == 1
    chord.store(H, np.diag(H))  # a fresh factor forgets the inverse
    assert chord.inverse is None and chord.uses == 0
    monkeypatch.setattr(_chord, "CHORD_INVERSE_MAX", n - 1)
    for b in rhs:
        z = chord.solve(b)
    assert chord.inverse is None and np.linalg.norm(z - np.linalg.solve(H, b)) <= 1e-12 * np.linalg.norm(z)
