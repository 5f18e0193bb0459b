"""The on-disk cache of a frame model's precompute: a second run loads it and gives the same model."""

from __future__ import annotations

import numpy as np
import pytest

import voxflex as vf
from voxflex import cache
from voxflex.scene import FixedSpec, LoadSpec, MaterialSpec, NodesSpec, ObjectSpec, ProbeSpec, Scene


def _scene(seed=0):
    return Scene(object=ObjectSpec(shape="box", size=(0.4, 0.2, 0.2), voxel_size=0.05),
                 materials=(MaterialSpec(model="neo-hookean", young=1e4, poisson=0.3, density=100.0),),
                 nodes=NodesSpec(kind="affine", count=8, seed=seed), fixed=(FixedSpec(max=(1e-6, 1e9, 1e9)),),
                 loads=(LoadSpec(kind="gravity"),), probes=(ProbeSpec("tip", (0.4, 0.1, 0.1)),))


def test_second_run_loads_the_precompute_and_gives_the_same_result(tmp_path, monkeypatch):
    monkeypatch.setenv("VOXFLEX_CACHE_DIR", str(tmp_path / "cache"))
    first = vf.simulate(_scene(), progress=False)
    assert first.model["precompute_cached"] is False
    assert len(list((tmp_path / "cache" / "frames").glob("*.npz"))) == 1
    second = vf.simulate(_scene(), progress=False)
    assert second.model["precompute_cached"] is True
    # the same frames, weights and samples: the same answer bit for bit
    assert np.array_equal(first.nodes_state, second.nodes_state)
    assert np.array_equal(first.surface_positions, second.surface_positions)
    fresh = vf.simulate(_scene(), progress=False, cache=False)
    assert fresh.model["precompute_cached"] is False and np.array_equal(fresh.nodes_state, first.nodes_state)
    # another setting is another entry
    vf.simulate(_scene(seed=1), progress=False)
    assert len(list((tmp_path / "cache" / "frames").glob("*.npz"))) == 2


@pytest.mark.parametrize("quadrature", ["elaston", "gauss-legendre", "bare-midpoint"])
def test_every_quadrature_reloads_to_the_same_model(tmp_path, monkeypatch, quadrature):
    """The stabilised mid-point regions (above), elastons (their sub-rules' points), Gauss-Legendre and the
    bare mid-point rule: a model rebuilt from the cache entry has the same samples, energy, gradient and
    Hessian bit for bit, and the same recorded sample-count choice."""
    from dataclasses import replace

    monkeypatch.setenv("VOXFLEX_CACHE_DIR", str(tmp_path / "cache"))
    scene = _scene()
    el = scene.elasticity
    scene = replace(scene, elasticity=replace(el, quadrature=quadrature.replace("bare-", ""),
                                              hourglass="none" if quadrature.startswith("bare") else el.hourglass))
    first = vf.model(scene)
    second = vf.model(scene)
    assert not first.info["precompute_cached"] and second.info["precompute_cached"]
    assert first.info.get("samples_chosen") == second.info.get("samples_chosen")
    assert np.array_equal(first.samples.points, second.samples.points)
    q = first.rest + 1e-3 * np.random.default_rng(0).standard_normal(first.rest.shape)
    for a, b in zip(first.energy_gradient_hessian(q), second.energy_gradient_hessian(q)):
        assert np.array_equal(np.asarray(a), np.asarray(b))


def test_a_damaged_entry_is_recomputed_with_a_warning(tmp_path, monkeypatch):
    monkeypatch.setenv("VOXFLEX_CACHE_DIR", str(tmp_path / "cache"))
    vf.simulate(_scene(), progress=False)
    (entry,) = (tmp_path / "cache" / "frames").glob("*.npz")
    entry.write_bytes(b"not an npz file")
    with pytest.warns(cache.CacheWarning, match="unreadable"):
        result = vf.simulate(_scene(), progress=False)
    assert result.model["precompute_cached"] is False
    assert cache.load("frames", entry.stem) is not None  # rewritten


def test_the_cache_can_be_switched_off(tmp_path, monkeypatch):
    monkeypatch.setenv("VOXFLEX_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("VOXFLEX_CACHE", "0")
    vf.simulate(_scene(), progress=False)
    assert not (tmp_path / "cache").exists()
