"""The precompute cache can only return what a fresh build would (issue 27): its key covers the source of
the whole package, each entry carries the checksum of its arrays, and anything unreadable, damaged or
inconsistent is recomputed with a one-line warning -- never trusted, never blamed on the scene."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

import voxflex as vf
from voxflex import cache
from voxflex.scene import FixedSpec, LoadSpec, MaterialSpec, NodesSpec, ObjectSpec, ProbeSpec, Scene


def _scene():
    return Scene(object=ObjectSpec(shape="box", size=(0.4, 0.2, 0.2), voxel_size=0.05),
                 materials=(MaterialSpec(model="neo-hookean", young=1e4, poisson=0.3, density=100.0),),
                 nodes=NodesSpec(kind="affine", count=8), fixed=(FixedSpec(max=(1e-6, 1e9, 1e9)),),
                 loads=(LoadSpec(kind="gravity"),), probes=(ProbeSpec("tip", (0.4, 0.1, 0.1)),))


@pytest.fixture
def entry(tmp_path, monkeypatch):
    """A fresh cache holding the scene's entry; returns (its path, the fresh answer)."""
    monkeypatch.setenv("VOXFLEX_CACHE_DIR", str(tmp_path / "cache"))
    fresh = vf.simulate(_scene(), progress=False)
    (path,) = (tmp_path / "cache" / "frames").glob("*.npz")
    return path, fresh


def _arrays(path):
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def _rerun_and_compare(fresh, match):
    with pytest.warns(cache.CacheWarning, match=match) as caught:
        again = vf.simulate(_scene(), progress=False)
    assert all("\n" not in str(w.message) for w in caught)  # one line each
    assert again.model["precompute_cached"] is False
    assert np.array_equal(again.nodes_state, fresh.nodes_state)  # what a fresh build gives, bit for bit
    return again


def test_an_edited_but_valid_entry_is_not_used(entry):
    """The weights scaled by 1.01 and saved as a valid .npz: the checksum no longer matches."""
    path, fresh = entry
    d = _arrays(path)
    d["samples_w"] = d["samples_w"] * 1.01
    np.savez(path, **d)
    _rerun_and_compare(fresh, "checksum does not match")
    assert cache.load("frames", path.stem) is not None  # replaced by a good entry


def test_an_entry_without_a_checksum_is_not_used(entry):
    path, fresh = entry
    d = _arrays(path)
    d.pop(cache.CHECKSUM)
    np.savez(path, **d)
    _rerun_and_compare(fresh, "has no checksum")


@pytest.mark.parametrize("keep", [0.5, 0.9, 0.1])
def test_a_truncated_entry_is_recomputed(entry, keep):
    path, fresh = entry
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])
    _rerun_and_compare(fresh, "unreadable")


@pytest.mark.parametrize("edit", ["index_out_of_range", "nan_weights", "missing_array", "wrong_labels",
                                  "short_weights"])
def test_an_inconsistent_entry_with_a_valid_checksum_is_recomputed(entry, edit):
    """Entries forged with a matching checksum (a bug, a foreign writer): the builder finds them inconsistent
    and recomputes instead of raising an error about the scene."""
    path, fresh = entry
    d = _arrays(path)
    d.pop(cache.CHECKSUM)
    if edit == "index_out_of_range":
        d["samples_index"][0, 0] = 10_000
    elif edit == "nan_weights":
        d["samples_w"][0, 0] = np.nan
    elif edit == "missing_array":
        d.pop("samples_dw")
    elif edit == "wrong_labels":
        d["samples_label"][:] = 7
    else:
        key = "W_indptr" if "W_indptr" in d else "rk_indptr"  # natural-neighbour or reproducing-kernel
        d[key] = d[key][:-5]
    cache.save("frames", path.stem, d)
    _rerun_and_compare(fresh, "does not fit this image")


def test_a_damaged_entry_through_the_cli_is_a_warning_and_exit_0(entry, tmp_path):
    """In a child process (the command line's own warning printer): one line naming the entry, exit 0, the
    answer of a fresh build."""
    import os
    import subprocess
    import sys

    path, fresh = entry
    path.write_bytes(b"\x00" * 100)
    (tmp_path / "s.toml").write_text(_scene().to_toml())
    root = cache.source_files.__globals__["Path"](cache.__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": str(root), "VOXFLEX_PROGRESS": "0"}
    proc = subprocess.run([sys.executable, "-m", "voxflex", "simulate", "s.toml", "-o", "r.h5", "--quiet"],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("voxflex simulate: warning: cache entry"), proc.stderr
    assert "unreadable" in lines[0] and lines[0].endswith("(CacheWarning)")
    r = vf.Result.load(tmp_path / "r.h5")
    assert np.array_equal(r.nodes_state[-1], fresh.nodes_state[-1])


def test_the_fingerprint_covers_every_module_of_the_package(tmp_path):
    """A change in the frame model (outside the voronoi / sampling / build files the old fingerprint read)
    changes the key."""
    root = tmp_path / "voxflex"
    shutil.copytree(cache.source_files.__globals__["Path"](cache.__file__).parent, root,
                    ignore=shutil.ignore_patterns("__pycache__"))
    before = cache.source_fingerprint(root)
    names = {p.relative_to(root).as_posix() for p in cache.source_files(root)}
    assert {"deform/models/frames/model.py", "deform/models/frames/build.py", "deform/materials/laws.py",
            "voronoi/weights.py", "sampling/sampler.py", "cache.py"} <= names
    target = root / "deform" / "models" / "frames" / "model.py"
    target.write_text(target.read_text() + "\n# a change\n")
    assert cache.source_fingerprint(root) != before
    assert cache.source_fingerprint(root) == cache.source_fingerprint(root)  # deterministic


def test_the_checksum_sees_every_array_name_dtype_and_shape():
    a = {"x": np.arange(6.0), "y": np.ones((2, 3))}
    base = cache.checksum(a)
    assert cache.checksum({"x": np.arange(6.0), "y": np.ones((3, 2))}) != base
    assert cache.checksum({"x": np.arange(6), "y": np.ones((2, 3))}) != base
    assert cache.checksum({"z": np.arange(6.0), "y": np.ones((2, 3))}) != base
    assert cache.checksum({"y": np.ones((2, 3)), "x": np.arange(6.0)}) == base  # name order does not matter


@pytest.mark.parametrize("value, on", [("0", False), ("off", False), ("1", True), ("ON", True), (" yes ", True)])
def test_the_cache_switch_reads_its_values(value, on, monkeypatch):
    monkeypatch.setenv("VOXFLEX_CACHE", value)
    assert cache.enabled() is on


def test_an_unknown_cache_switch_is_refused(monkeypatch, tmp_path, capfd):
    """VOXFLEX_CACHE=maybe was taken as on without a word; now one line naming the values that work."""
    from robust import assert_refused, beam

    from voxflex.cli import main

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("VOXFLEX_CACHE", "maybe")
    monkeypatch.setenv("VOXFLEX_PROGRESS", "0")
    (tmp_path / "s.toml").write_text(beam("affine", nodes="count = 4"))
    status = main(["simulate", "s.toml", "-o", "r.h5", "--quiet"])
    assert_refused(status, capfd.readouterr()[1], "simulate", ["VOXFLEX_CACHE='maybe' is not a switch", "0 (off)"])
