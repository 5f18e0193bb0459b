"""Start-up guards: what ``import voxflex``, the command line and the default scene's path import.

Most of what ``voxflex simulate`` on the bundled scene waits for is imports
(``benchmarks/bench_startup.py`` measures it).  These tests keep the heavy
modules out of the paths that do not need them, by looking at ``sys.modules``
of a fresh interpreter -- never at wall-clock times.  Binary STL files (the
default scene's mesh) are read without pyvista; the reader is checked bitwise
against VTK's own STL reader (through pyvista), the independent oracle.
"""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import paths
import pytest

ROOT = paths.ROOT
BAR = ROOT / "data" / "bar.stl"  # the default scene's mesh

# modules that no voxflex start-up needs: rendering and VTK I/O, progress bars, optional scientific stacks
VISUAL = ("pyvista", "vtkmodules", "vtk", "matplotlib")
# what `voxflex --help` (parse the command line) must not import either: each command imports its own
COMPUTE = ("numpy", "scipy", "numba", "h5py", "skimage", "pyamg", "tqdm")


def _loaded_after(code: str, env_extra: dict | None = None) -> dict:
    """Run ``code`` in a fresh interpreter (this checkout first on the path) and return its JSON line,
    to which the top-level names of every loaded module are added under ``"modules"``."""
    probe = code + (
        "\nimport json as _j, sys as _s\n"
        "_out = dict(globals().get('OUT', {}))\n"
        "_out['modules'] = sorted({m.split('.')[0] for m in _s.modules})\n"
        "print(_j.dumps(_out))\n"
    )
    env = dict(os.environ, PYTHONPATH=str(ROOT), **(env_extra or {}))
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=env, cwd=ROOT,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_import_and_command_line_parser_import_nothing_heavy():
    out = _loaded_after(
        "import voxflex, voxflex.cli\n"
        "voxflex.cli.build_parser()\n"
        "OUT = {'file': voxflex.__file__}\n"
    )
    assert Path(out["file"]).resolve().parent == ROOT / "voxflex"  # this checkout's package was probed
    heavy = sorted(set(out["modules"]) & set(VISUAL + COMPUTE))
    assert heavy == [], f"import voxflex / voxflex --help imported {heavy}; import them inside the functions"


def test_public_names_still_resolve_lazily():
    # docs/api.md's entry points: `import voxflex as vf` then vf.<name>; each resolves on first use
    out = _loaded_after(
        "import voxflex as vf\n"
        "names = [n for n in vf.__all__ if not n.startswith('__')]\n"
        "OUT = {'missing': [n for n in names if getattr(vf, n, None) is None]}\n"
    )
    assert out["missing"] == []


def test_default_scene_path_never_imports_pyvista(tmp_path):
    """A scene shaped like the bundled default (binary STL mesh, affine frames, mid-point samples,
    gravity, static steps, a probe, the result file) at a small size: no pyvista, VTK or tqdm.

    The kernels run as plain Python (``VOXFLEX_DISABLE_JIT=1``) so that a fresh checkout does not
    spend a minute compiling them here; which modules are imported does not depend on it.
    """
    scene = tmp_path / "small.toml"
    scene.write_text(
        f'[object]\nmesh = "{BAR.as_posix()}"\nvoxel_size = 0.0025\n'
        '[[material]]\nlabel = 1\nmodel = "neo-hookean"\nyoung = 1.0e5\npoisson = 0.45\ndensity = 1100.0\n'
        '[nodes]\nkind = "affine"\ncount = 4\n'
        '[elasticity]\nquadrature = "midpoint"\nsamples = 40\n'
        '[[fixed]]\nmin = [-1.0, -1.0, -1.0]\nmax = [0.003, 1.0, 1.0]\n'
        '[[load]]\nkind = "gravity"\nvector = [0.0, 0.0, -9.81]\n'
        '[solver]\nkind = "static"\nsteps = 1\n'
        '[[probe]]\nname = "tip"\npoint = [0.049, 0.0, 0.0]\n'
    )
    result = tmp_path / "small.h5"
    out = _loaded_after(
        "from voxflex.cli import main\n"
        f"OUT = {{'rc': main(['simulate', {str(scene)!r}, '--quiet', '-o', {str(result)!r}])}}\n",
        env_extra={"VOXFLEX_DISABLE_JIT": "1"},
    )
    assert out["rc"] == 0 and result.is_file()
    heavy = sorted(set(out["modules"]) & set(VISUAL + ("tqdm",)))
    assert heavy == [], f"the default scene's path imported {heavy}"


def test_default_scene_is_a_binary_stl():
    # the fast path above is only taken for binary STL: if the bundled mesh changes format, say so here
    from voxflex.rasterize.mesh import _read_binary_stl
    from voxflex.scene import Scene, default_scene_path

    scene = Scene.from_toml(default_scene_path())
    assert Path(scene.object.mesh).name == BAR.name
    assert _read_binary_stl(Path(scene.object.mesh)) is not None


def _write_binary_stl(path: Path, triangles: np.ndarray, header: bytes = b"voxflex test") -> None:
    from voxflex.rasterize.mesh import _STL_TRIANGLE

    records = np.zeros(len(triangles), dtype=_STL_TRIANGLE)
    records["vertices"] = triangles
    with open(path, "wb") as fh:
        fh.write(header.ljust(80, b" ")[:80] + struct.pack("<I", len(triangles)) + records.tobytes())


def _read_with_vtk(path: Path):
    """The same file through VTK's STL reader (the path load_mesh takes for any other file)."""
    import voxflex.rasterize.mesh as mesh_module

    original = mesh_module._read_binary_stl
    mesh_module._read_binary_stl = lambda _path: None
    try:
        return mesh_module.load_mesh(path)
    finally:
        mesh_module._read_binary_stl = original


def _assert_same_mesh(a, b):
    # bitwise: the voxelized image, hence the whole run, depends on these arrays only
    assert a.vertices.shape == b.vertices.shape and a.faces.shape == b.faces.shape
    assert a.vertices.tobytes() == b.vertices.tobytes()
    assert np.array_equal(a.faces, b.faces)


def test_binary_stl_reads_as_vtk_reads_it_bar():
    pytest.importorskip("pyvista")
    from voxflex.rasterize.mesh import load_mesh

    _assert_same_mesh(load_mesh(BAR), _read_with_vtk(BAR))


def test_binary_stl_reads_as_vtk_reads_it_merging_and_degenerate(tmp_path):
    """Shared corners merged in order of first appearance, -0.0 merged with 0.0 (VTK compares values),
    a degenerate triangle's corners kept as vertices while the triangle is dropped."""
    pytest.importorskip("pyvista")
    from voxflex.rasterize.mesh import load_mesh

    rng = np.random.default_rng(3)
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], dtype=np.float32) - 0.5
    corners[0] = [0.0, -0.5, -0.5]
    tets = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3], [1, 2, 4], [4, 4, 3]]  # the last one degenerate
    triangles = corners[np.array(tets)].copy()
    triangles[1, 0, 0] = np.float32(-0.0)  # the same corner as triangles[0, 0], written as -0.0
    triangles = triangles[rng.permutation(len(triangles))]
    path = tmp_path / "merge.stl"
    _write_binary_stl(path, triangles)
    fast, vtk = load_mesh(path), _read_with_vtk(path)
    _assert_same_mesh(fast, vtk)
    assert len(fast.vertices) == 5 and len(fast.faces) == 5


def test_binary_stl_reads_as_vtk_reads_it_shared_meshes(tmp_path):
    pv = pytest.importorskip("pyvista")
    from voxflex.rasterize.mesh import load_mesh

    meshes = Path(os.environ.get("VOXFLEX_SHARED", ROOT.parent / "shared")) / "meshes"
    if not (meshes / "spot.obj").is_file():
        pytest.skip(f"shared test meshes not found at {meshes} (set VOXFLEX_SHARED)")
    for name in ("spot", "fandisk"):
        path = tmp_path / f"{name}.stl"
        pv.read(meshes / f"{name}.obj").triangulate().save(path, binary=True)
        _assert_same_mesh(load_mesh(path), _read_with_vtk(path))


def test_other_stl_files_still_go_through_vtk(tmp_path):
    """ASCII STL, a binary header starting with 'solid', a size that disagrees with the count: no fast path."""
    from voxflex.rasterize.mesh import _read_binary_stl

    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], dtype=np.float32)
    ascii_stl = tmp_path / "ascii.stl"
    ascii_stl.write_text("solid t\n facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n   vertex 1 0 0\n"
                         "   vertex 0 1 0\n  endloop\n endfacet\nendsolid t\n")
    solid_header = tmp_path / "solid.stl"
    _write_binary_stl(solid_header, tri, header=b"solid but binary")
    truncated = tmp_path / "truncated.stl"
    _write_binary_stl(truncated, tri)
    truncated.write_bytes(truncated.read_bytes()[:-4])
    nan = tmp_path / "nan.stl"
    _write_binary_stl(nan, np.where(tri == 1, np.float32("nan"), tri))
    for path in (ascii_stl, solid_header, truncated, nan):
        assert _read_binary_stl(path) is None, path.name
    assert _read_binary_stl(BAR) is not None


def _program(args, code=None, tmp_path=None):
    """Run the voxflex program (``python -m voxflex ARGS``, or ``code`` that ends by calling
    ``voxflex.cli.entry()``) in a fresh interpreter with stdout and stderr on pipes."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    cmd = [sys.executable, "-m", "voxflex", *args] if code is None else [sys.executable, "-c", code]
    return subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=tmp_path or ROOT, timeout=120)


def test_program_exit_status_output_and_files(tmp_path):
    """entry() ends the process without the interpreter's teardown: the status, the buffered
    output on a pipe and the written file must be those of an ordinary exit."""
    from voxflex.image import LabelImage

    out = tmp_path / "box.npz"
    ok = _program(["voxelize", "box:1,1,1", "-o", str(out), "--voxel-size", "0.5"], tmp_path=tmp_path)
    assert ok.returncode == 0, ok.stderr
    assert ok.stdout.startswith(f"wrote {out}: 2x2x2 voxels") and ok.stdout.endswith("\n")
    assert LabelImage.load(out).shape == (2, 2, 2)
    bad = _program(["simulate", str(tmp_path / "missing.toml")], tmp_path=tmp_path)
    assert bad.returncode == 2 and bad.stdout == ""
    assert bad.stderr.count("\n") == 1 and "not found" in bad.stderr
    assert _program(["--version"]).stdout.startswith("voxflex ")  # argparse's SystemExit: the usual exit


def test_program_runs_atexit_handlers_and_waits_for_threads(tmp_path):
    out = tmp_path / "box.npz"
    argv = ["voxflex", "voxelize", "box:1,1,1", "-o", str(out), "--voxel-size", "0.5"]
    code = (
        "import atexit, sys, threading, time\n"
        "import voxflex.cli\n"
        "atexit.register(lambda: print('atexit handler ran'))\n"
        "{thread}"
        f"sys.argv = {argv!r}\n"
        "print('printed before the command')\n"
        "voxflex.cli.entry()\n"
    )
    plain = _program(None, code.format(thread=""), tmp_path)
    assert plain.returncode == 0, plain.stderr
    lines = plain.stdout.splitlines()
    assert lines[0] == "printed before the command" and lines[1].startswith("wrote ")
    assert lines[-1] == "atexit handler ran"
    # a non-daemon thread still running when the command returns (it waits for the command's file,
    # then 0.5 s more): the interpreter's own exit, which waits for the thread
    thread = (
        "def _late():\n"
        f"    while not __import__('os').path.exists({str(out)!r}):\n"
        "        time.sleep(0.01)\n"
        "    time.sleep(0.5)\n"
        "    print('thread finished')\n"
        "threading.Thread(target=_late).start()\n"
    )
    out.unlink()
    waited = _program(None, code.format(thread=thread), tmp_path)
    assert waited.returncode == 0, waited.stderr
    assert "thread finished" in waited.stdout and waited.stdout.rstrip().endswith("atexit handler ran")
