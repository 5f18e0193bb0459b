"""The robustness table of docs/robustness.md, measured: each case run through the command line (or the
Python API) of a given source tree, for the voxel model and for frames, with what came out.

Each case records the exit status, the last line on stderr (an error or a warning), whether a traceback
was printed, and a figure of the answer where the run exits 0 (a probe's displacement, a ratio to the
exact answer, the lowest drawn vertex...).  Run it once on the code before a change and once after, then
print the two side by side::

    python benchmarks/bench_robustness.py --tree /path/to/main --out before.json
    python benchmarks/bench_robustness.py --tree . --out now.json
    python benchmarks/bench_robustness.py --table before.json now.json

``--cases a,b`` runs some cases only (``--list`` names them).  Every case runs in a fresh folder with its
own precompute cache, in a child process with a 300 s limit.  The ``disk-full`` case needs root (a 3 MB
tmpfs) and is skipped otherwise.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import textwrap
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LIMIT = 300


def beam(kind="voxel", *, size=(4.0, 1.0, 1.0), h=0.25, model="hooke", young="1.0e4", poisson="0.3", density="1.0",
         gravity="[0.0, 0.0, -9.81]", nodes="", elasticity='strain = "linear"', solver="", fixed=True,
         fixed_max="[1.0e-6, 1.0e9, 1.0e9]", extra="", probe=None) -> str:
    probe = probe or [size[0], size[1] / 2, size[2] / 2]
    clamp = f"[[fixed]]\nmin = [-1.0e9, -1.0e9, -1.0e9]\nmax = {fixed_max}\n" if fixed else ""
    return (f'[object]\nshape = "box"\nsize = [{size[0]!r}, {size[1]!r}, {size[2]!r}]\nvoxel_size = {h!r}\n'
            f'origin = [0.0, 0.0, 0.0]\n\n[[material]]\nmodel = "{model}"\nyoung = {young}\npoisson = {poisson}\n'
            f'density = {density}\n\n[nodes]\nkind = "{kind}"\n{nodes}\n\n[elasticity]\n{elasticity}\n\n{clamp}\n'
            f'[[load]]\nkind = "gravity"\nvector = {gravity}\n\n[solver]\n{solver}\n\n[[probe]]\nname = "tip"\n'
            f"point = {list(probe)}\n{extra}")


def image_scene(image, kind, *, nodes="", elasticity='strain = "linear"', probe="[4.0, 0.5, 0.1]", solver=""):
    return (f'[object]\nimage = "{image}"\n\n[[material]]\nmodel = "hooke"\nyoung = 1.0e4\npoisson = 0.3\n'
            f'density = 1.0\n\n[nodes]\nkind = "{kind}"\n{nodes}\n\n[elasticity]\n{elasticity}\n\n[[fixed]]\n'
            'min = [-1.0e9, -1.0e9, -1.0e9]\nmax = [1.0e-6, 1.0e9, 1.0e9]\n\n[[load]]\nkind = "gravity"\n'
            f'vector = [0.0, 0.0, -9.81]\n\n[solver]\n{solver}\n\n[[probe]]\nname = "tip"\npoint = {probe}\n')


def frames(kind, n=20):
    return f"count = {n}" if kind == "affine" else ""


# -- what a case prints after an exit 0 (run with the tree's voxflex) --------------------------------------
TIP = "import numpy as np, voxflex as vf; r = vf.Result.load('r.h5'); p = r.probes['tip']; print('tip %.4g m' % (p[-1] - p[0])[2])"
TIP_OVER = ("import numpy as np, voxflex as vf; r = vf.Result.load('r.h5'); p = r.probes['{p}']; "
            "print('%.3g of exact' % ((p[-1] - p[0])[2] / ({exact})))")
DROP = ("import numpy as np, voxflex as vf; r = vf.Result.load('r.h5'); ob = r.problem['obstacles'][0]; "
        "n = np.asarray(ob['normal'], float); n /= np.linalg.norm(n); "
        "d = (r.surface_positions - np.asarray(ob['point'], float)) @ n; h = float(np.min(r.image_spacing)); "
        "W = r.n_voxels * np.prod(r.image_spacing) * 1000 * 9.81; f = np.linalg.norm(r.contact_force[-1, 0]); "
        "print('lowest vertex %+.2f %% of a voxel, contact / weight %.4f' % (100 * d.min() / h, f / W))")


def _two_blocks(folder):
    import numpy as np

    from voxflex.image import LabelImage

    lab = np.zeros((16, 4, 4), dtype=np.uint8)
    lab[:7] = lab[9:] = 1
    LabelImage(lab, spacing=0.25).save(folder / "two.npz")


def _plate(folder):
    import numpy as np

    from voxflex.image import LabelImage

    LabelImage(np.ones((16, 4, 1), dtype=np.uint8), spacing=(0.25, 0.25, 0.2)).save(folder / "plate.npz")


def _contrast(folder):
    import numpy as np

    from voxflex.image import LabelImage

    lab = np.ones((16, 4, 4), dtype=np.uint8)
    lab[8:] = 2
    LabelImage(lab, spacing=0.25).save(folder / "contrast.npz")


def cases():
    """{name: (kinds, build(folder, kind) -> (argv or None, python code or None, metric code or None))}."""
    C = {}

    def add(name, kinds=("voxel", "affine")):
        def deco(f):
            C[name] = (kinds, f)
            return f
        return deco

    def sim(folder, text, *extra, metric=TIP):
        (folder / "s.toml").write_text(text)
        return ["simulate", "s.toml", "-o", "r.h5", "--quiet", *extra], None, metric

    # -- rows that were there -----------------------------------------------------------------------
    add("no-support")(lambda f, k: sim(f, beam(k, nodes=frames(k), fixed=False)))

    @add("floating-island")
    def _(f, k):
        _two_blocks(f)
        return sim(f, image_scene("two.npz", k, nodes=frames(k), probe="[1.0, 0.5, 0.5]"))

    @add("contrast-1e4")
    def _(f, k):
        _contrast(f)
        text = image_scene("contrast.npz", k, nodes=frames(k), elasticity="", solver="steps = 5",
                           probe="[4.0, 0.5, 0.5]").replace('model = "hooke"\nyoung = 1.0e4',
                                                           'model = "neo-hookean"\nyoung = 1.0e3')
        text = text.replace("[[load]]", '[[material]]\nlabel = 2\nmodel = "neo-hookean"\nyoung = 1.0e7\npoisson = 0.3\n'
                                        'density = 1.0\n\n[[load]]')
        return sim(f, text)

    @add("free-fall-dt-1e-9")
    def _(f, k):
        text = (ROOT / "examples" / "drop.toml").read_text().replace("dt = 0.01", "dt = 1e-9")
        text = text.replace('kind = "voxel"', f'kind = "{k}"\n{frames(k, 8)}')
        return sim(f, text, metric=TIP_OVER.format(p="centre", exact="-9.81e-18 * 55"))

    @add("buckling-78x")
    def _(f, k):
        text = beam(k, model="neo-hookean", young="1.0e3", elasticity="", nodes=frames(k), gravity="[0.0, 0.0, -0.981]",
                    solver="steps = 5", fixed_max="[1.0e-9, 9.0, 9.0]",
                    extra='\n[[fixed]]\nmin = [3.999999999, -1.0, -1.0]\nmax = [9.0, 9.0, 9.0]\n'
                          'transform = [[0.5, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]\n',
                    probe=[2.0, 0.5, 0.5])
        return sim(f, text)

    add("one-step-large-sag")(lambda f, k: sim(f, beam(k, model="neo-hookean", young="1.0e3", elasticity="",
                                                       nodes=frames(k), solver="steps = 1\nmax_iterations = 6")))
    add("locking-nu-0.4999")(lambda f, k: sim(f, beam(k, poisson="0.4999", nodes=frames(k))))
    add("few-samples", kinds=("affine",))(lambda f, k: sim(f, beam(k, h=0.5, nodes="count = 20",
                                                                  elasticity='strain = "linear"\nsamples = 32')))
    add("stvk-squashed")(lambda f, k: sim(f, beam(k, model="stvk", young="1.0e3", elasticity="", nodes=frames(k),
                                                  gravity="[0.0, 0.0, -200.0]", solver="steps = 4")))

    @add("output-over-scene")
    def _(f, k):
        (f / "s.toml").write_text(beam(k, nodes=frames(k)))
        return ["simulate", "s.toml", "-o", "s.toml", "--quiet"], None, None

    add("steps-1e9")(lambda f, k: sim(f, beam(k, nodes=frames(k), solver="steps = 1000000000")))
    add("4M-voxels")(lambda f, k: sim(f, beam(k, nodes=frames(k), h=0.01, probe=[3.995, 0.5, 0.5])))

    # -- issue 27 ------------------------------------------------------------------------------------
    add("one-held-frame", kinds=("affine",))(lambda f, k: sim(f, beam(k, nodes="count = 1")))
    add("clamp-over-all")(lambda f, k: sim(f, beam(k, nodes=frames(k, 4), fixed_max="[1.0e9, 1.0e9, 1.0e9]")))
    add("parents-2", kinds=("affine",))(lambda f, k: sim(f, beam(k, nodes="count = 20\nparents = 2")))
    add("parents-1-gauss", kinds=("affine",))(lambda f, k: sim(f, beam(
        k, nodes="count = 20\nparents = 1", elasticity='strain = "linear"\nquadrature = "gauss-legendre"')))

    @add("thin-plate-midpoint", kinds=("affine",))
    def _(f, k):
        _plate(f)
        return sim(f, image_scene("plate.npz", k, nodes="count = 10"))

    @add("thin-plate-gauss")
    def _(f, k):
        _plate(f)
        return sim(f, image_scene("plate.npz", k, nodes=frames(k, 10),
                                  elasticity='strain = "linear"\nquadrature = "gauss-legendre"'))

    for s in ("1e-6", "1e-2", "1e3"):
        def scaled(f, k, s=float(s)):
            text = beam(k, size=(4 * s, s, s), h=0.25 * s, model="neo-hookean", elasticity="", nodes=frames(k),
                        gravity=f"[0.0, 0.0, {-9.81 / s!r}]", fixed_max=f"[{1e-6 * s!r}, {2 * s!r}, {2 * s!r}]",
                        solver="steps = 2")
            text = text.replace("min = [-1.0e9, -1.0e9, -1.0e9]", f"min = [{-s!r}, {-s!r}, {-s!r}]")
            return sim(f, text, metric=f"import voxflex as vf; r = vf.Result.load('r.h5'); p = r.probes['tip']; "
                                       f"print('tip / size %.6g' % ((p[-1] - p[0])[2] / {s!r}))")
        add(f"scale-{s}")(scaled)

    add("gravity-1e200")(lambda f, k: sim(f, beam(k, nodes=frames(k), gravity="[0.0, 0.0, -1e200]")))
    add("gravity-1e30")(lambda f, k: sim(f, beam(k, nodes=frames(k), gravity="[0.0, 0.0, -1e30]")))
    add("young-1e-300")(lambda f, k: sim(f, beam(k, nodes=frames(k), young="1e-300")))
    add("young-5e-324")(lambda f, k: sim(f, beam(k, nodes=frames(k), young="5e-324")))
    add("plasticity-elastons", kinds=("affine",))(lambda f, k: sim(f, beam(
        k, nodes="count = 6", elasticity='quadrature = "elaston"',
        density='1.0\nstrain = "linear"\nyield_strain = 1.0e-3')))

    @add("api-output-over-scene", kinds=("voxel",))
    def _(f, k):
        (f / "s.toml").write_text(beam(k))
        return None, _api("vf.simulate('s.toml', progress=False, output='s.toml')"), \
            "print('scene file intact' if open('s.toml', 'rb').read().startswith(b'[object]') else 'SCENE FILE OVERWRITTEN')"

    @add("api-output-over-foreign-h5", kinds=("voxel",))
    def _(f, k):
        (f / "s.toml").write_text(beam(k))
        (f / "notes.h5").write_text("precious\n")
        return None, _api("vf.simulate('s.toml', progress=False, output='notes.h5')"), \
            "print('notes intact' if open('notes.h5', 'rb').read() == b'precious\\n' else 'NOTES OVERWRITTEN')"

    for what in ("edited", "truncated"):
        @add(f"cache-{what}", kinds=("affine",))
        def _(f, k, what=what):
            (f / "s.toml").write_text(beam(k, nodes="count = 8"))
            code = textwrap.dedent(f"""\
                import glob, numpy as np, voxflex as vf
                fresh = vf.simulate('s.toml', progress=False)
                (path,) = glob.glob('cache/frames/*.npz')
                if '{what}' == 'edited':
                    d = dict(np.load(path)); d['samples_w'] = d['samples_w'] * 1.01; np.savez(path, **d)  # a valid entry, edited
                else:
                    data = open(path, 'rb').read(); open(path, 'wb').write(data[: len(data) // 2])
                again = vf.simulate('s.toml', progress=False)
                same = np.array_equal(again.nodes_state, fresh.nodes_state)
                print('same as fresh' if same else 'DIFFERS from a fresh build by %.3g' %
                      np.abs(again.nodes_state - fresh.nodes_state).max())""")
            return None, code, None

    @add("render-nan", kinds=("voxel",))
    def _(f, k):
        (f / "s.toml").write_text(beam(k))
        code = textwrap.dedent("""\
            import h5py, voxflex as vf
            vf.simulate('s.toml', progress=False, output='g.h5')
            with h5py.File('g.h5', 'r+') as h:
                a = h['surface/positions'][()]; a[-1, 3] = float('nan'); h['surface/positions'][...] = a""")
        return ["render", "g.h5", "-o", "g.png"], code, None

    @add("damaged-result-info", kinds=("voxel",))
    def _(f, k):
        (f / "s.toml").write_text(beam(k))
        code = textwrap.dedent("""\
            import random, voxflex as vf
            vf.simulate('s.toml', progress=False, output='g.h5')
            d = bytearray(open('g.h5', 'rb').read()); r = random.Random(0)
            for _ in range(200):
                i = r.randrange(512, len(d)); d[i] = r.randrange(256)
            open('g.h5', 'wb').write(bytes(d))""")
        return ["info", "g.h5"], code, None

    @add("long-output-name", kinds=("voxel",))
    def _(f, k):
        (f / "s.toml").write_text(beam(k))
        return ["simulate", "s.toml", "-o", "a" * 250 + ".h5", "--quiet"], None, None

    @add("render-to-proc", kinds=("voxel",))
    def _(f, k):
        (f / "s.toml").write_text(beam(k))
        return ["render", "g.h5", "-o", "/proc/x.png"], "import voxflex as vf\nvf.simulate('s.toml', progress=False, output='g.h5')", None

    @add("tradeoff-to-proc", kinds=("voxel",))
    def _(f, k):
        (f / "s.toml").write_text(beam(k, h=0.5))
        return ["tradeoff", "s.toml", "-o", "/proc/x", "--frames", "4", "--quiet"], None, None

    @add("voxel-levels-50", kinds=("voxel",))
    def _(f, k):
        (f / "s.toml").write_text(beam(k, h=0.5))
        return ["tradeoff", "s.toml", "-o", "sweep", "--voxel-levels", "50", "--frames", "4", "--quiet"], None, None

    @add("scheduler-silent-port", kinds=("voxel",))
    def _(f, k):
        (f / "s.toml").write_text(beam(k, h=0.5))
        return ["tradeoff", "s.toml", "-o", "sweep", "--frames", "4", "--quiet", "--scheduler", "SILENT"], None, None

    @add("corrupt-sdf", kinds=("voxel",))
    def _(f, k):
        np_code = "import numpy as np; np.savez('sdf.npz', distance=np.zeros((8, 8, 8)), spacing=np.ones(3), origin=np.zeros(3))"
        subprocess.run([sys.executable, "-c", np_code], cwd=f, check=True)
        data = (f / "sdf.npz").read_bytes()
        (f / "sdf.npz").write_bytes(data[: len(data) // 2])
        return sim(f, beam(k, h=0.5, extra='\n[[obstacle]]\nkind = "sdf"\nfile = "sdf.npz"\n'))

    @add("disk-full", kinds=("voxel",))
    def _(f, k):
        return ["DISK-FULL"], None, None

    @add("drop-box-plane")
    def _(f, k):
        text = _drop_text(k, "[0.0, 0.0, 1.0]", 75, 0.01)
        return sim(f, text, metric=DROP)

    @add("drop-box-tilted-plane")
    def _(f, k):
        return sim(f, _drop_text(k, "[0.4, 0.0, 1.0]", 20, 0.02), metric=DROP)

    @add("friction-1e12", kinds=("voxel",))
    def _(f, k):
        text = (ROOT / "examples" / "ball_on_plane.toml").read_text()
        text = text.replace("normal = [0.0, 0.0, 1.0]", "normal = [0.0, 0.0, 1.0]\nfriction = 1e12")
        text = text.replace("vector = [0.0, 0.0, -9.81]", "vector = [3.0, 0.0, -9.81]").replace("steps = 50", "steps = 10")
        return sim(f, text, metric="print('exit 0')")

    @add("neo-hooke-frame-advice", kinds=("affine",))
    def _(f, k):
        (f / "s.toml").write_text(beam(k, model="neo-hookean", elasticity="", nodes="count = 6"))
        return None, "import voxflex as vf\nprint(vf.model(vf.Scene.from_toml('s.toml')).advice())", None

    @add("flat-membrane", kinds=("membrane",))
    def _(f, k):
        V = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 0]]
        F = [[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]]
        (f / "flat.obj").write_text("".join(f"v {a} {b} {c}\n" for a, b, c in V)
                                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F))
        text = ('[object]\nmesh = "flat.obj"\nvoxel_size = 0.1\n\n[[material]]\nmodel = "stvk"\nyoung = 2.0e9\n'
                'poisson = 0.3\ndensity = 1400.0\n\n[nodes]\nkind = "membrane"\n\n[membrane]\nthickness = 5.0e-5\n'
                'rim = "clamped"\n\n[[load]]\nkind = "pressure"\npressure = 100.0\n\n[[probe]]\nname = "tip"\n'
                'point = [0.5, 0.5, 0.0]\n')
        return sim(f, text)

    @add("folder-as-scene", kinds=("voxel",))
    def _(f, k):
        (f / "scene.toml").mkdir()
        return ["simulate", "scene.toml", "-o", "r.h5", "--quiet"], None, None

    @add("count-1e8-small-disk", kinds=("affine",))
    def _(f, k):
        return ["COUNT-SMALL-DISK"], None, None

    return C


def _api(call: str) -> str:
    """Python code running ``call``: a VoxflexError is printed as one line on stderr and exits 2 (as the CLI)."""
    return ("import sys, voxflex as vf\ntry:\n    " + call + "\nexcept vf.VoxflexError as exc:\n"
            "    print('error:', exc, file=sys.stderr); sys.exit(2)")


def _drop_text(kind, normal, steps, z):
    nodes = "count = 10" if kind == "affine" else ""
    return (f'[object]\nshape = "box"\nsize = [1.0, 1.0, 0.5]\nvoxel_size = 0.25\norigin = [0.0, 0.0, {z!r}]\n\n'
            '[[material]]\nmodel = "neo-hookean"\nyoung = 1.0e5\npoisson = 0.3\ndensity = 1000.0\n\n'
            f'[nodes]\nkind = "{kind}"\n{nodes}\n\n[[load]]\nkind = "gravity"\nvector = [0.0, 0.0, -9.81]\n\n'
            f'[[obstacle]]\nkind = "plane"\npoint = [0.0, 0.0, 0.0]\nnormal = {normal}\n\n'
            f'[solver]\nkind = "implicit-euler"\ndt = 0.02\nsteps = {steps}\n')


def _silent_server():
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(8)
    conns = []

    def serve():
        while True:
            try:
                conns.append(sock.accept()[0])
            except OSError:
                return

    threading.Thread(target=serve, daemon=True).start()
    return sock, f"tcp://127.0.0.1:{sock.getsockname()[1]}"


def _run(tree: Path, name: str, kind: str, build) -> dict:
    folder = Path(tempfile.mkdtemp(prefix=f"robust-{name}-"))
    env = {**os.environ, "PYTHONPATH": str(tree), "VOXFLEX_PROGRESS": "0", "VOXFLEX_CACHE_DIR": str(folder / "cache"),
           "PYVISTA_OFF_SCREEN": "true"}
    out = {"case": name, "kind": kind}
    server = mount = None
    try:
        argv, code, metric = build(folder, kind)
        if code:
            p = subprocess.run([sys.executable, "-c", code], cwd=folder, env=env, capture_output=True, text=True,
                               timeout=LIMIT)
            if argv is None:
                out.update(_outcome(p))
                if p.returncode == 0 and metric:
                    out["answer"] = _metric(metric, folder, env)
                return out
        if argv == ["DISK-FULL"] or argv == ["COUNT-SMALL-DISK"]:
            if os.geteuid() != 0:
                return {**out, "skipped": "needs root for a small tmpfs"}
            mount = folder / "small"
            mount.mkdir()
            subprocess.run(["mount", "-t", "tmpfs", "-o", "size=3m", "tmpfs", str(mount)], check=True)
            if argv == ["COUNT-SMALL-DISK"]:
                (folder / "s.toml").write_text(beam("affine", nodes="count = 100000000"))
                argv = ["simulate", "s.toml", "-o", str(mount / "r.h5"), "--quiet"]
            else:
                (folder / "s.toml").write_text(beam("voxel", solver="steps = 150"))
                argv = ["simulate", "s.toml", "-o", str(mount / "r.h5"), "--quiet"]
                # the run is accepted (2.5 of 3 MB), then the disk fills under it (the file is written at the end)
                filler = threading.Timer(1.5, lambda: subprocess.run(
                    ["dd", "if=/dev/zero", f"of={mount / 'fill'}", "bs=1k", "count=3000"], capture_output=True))
                filler.start()
        if "SILENT" in argv:
            server, address = _silent_server()
            argv = [address if a == "SILENT" else a for a in argv]
        t0 = time.perf_counter()
        try:
            p = subprocess.run([sys.executable, "-m", "voxflex", *argv], cwd=folder, env=env, capture_output=True,
                               text=True, timeout=60 if server else LIMIT)
        except subprocess.TimeoutExpired:
            return {**out, "rc": "timeout", "line": f"still running after {60 if server else LIMIT} s"}
        out.update(_outcome(p), seconds=round(time.perf_counter() - t0, 1))
        if p.returncode == 0 and metric:
            out["answer"] = _metric(metric, folder, env)
        return out
    finally:
        if server is not None:
            server[0].close() if isinstance(server, tuple) else server.close()
        if mount is not None:
            subprocess.run(["umount", str(mount)], capture_output=True)
        shutil.rmtree(folder, ignore_errors=True)


def _metric(code, folder, env) -> str:
    m = subprocess.run([sys.executable, "-c", code], cwd=folder, env=env, capture_output=True, text=True,
                       timeout=LIMIT)
    lines = m.stdout.strip().splitlines() or m.stderr.strip().splitlines()
    return lines[-1][:160] if lines else ""


def _outcome(p) -> dict:
    err = [ln for ln in p.stderr.strip().splitlines() if ln.strip()]
    tb = any(ln.startswith("Traceback") for ln in err)
    line = err[-1] if err else ""
    warn = [ln for ln in err if ": warning: " in ln or "Warning:" in ln]
    out = {"rc": p.returncode, "traceback": tb, "line": line[:300]}
    if warn:
        out["warnings"] = [w[:200] for w in warn[-2:]]
    if p.stdout.strip():
        out["stdout"] = p.stdout.strip().splitlines()[-1][:200]
    return out


def _cell(r) -> str:
    if r is None:
        return ""
    if "skipped" in r:
        return f"skipped ({r['skipped']})"
    if r.get("rc") == "timeout":
        return r["line"]
    if r.get("traceback"):
        return f"traceback (exit {r['rc']}): {r['line'].split(':')[0]}"
    if r["rc"] == 0:
        what = r.get("answer") or r.get("stdout") or ""
        warn = r.get("warnings")
        if warn:
            w = warn[-1]
            what += f"; warns: {w.split('warning: ')[-1] if 'warning: ' in w else w}"
        return f"exit 0: {what}".strip()
    line = r["line"].split("error: ", 1)[-1]
    return f"exit {r['rc']}: {line}"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tree", type=Path, default=ROOT, help="source tree to run (its voxflex/ is imported)")
    ap.add_argument("--out", type=Path, help="write the outcomes as JSON lines")
    ap.add_argument("--cases", help="comma-separated case names (default: all)")
    ap.add_argument("--kinds", help="comma-separated node kinds to run (default: each case's own)")
    ap.add_argument("--list", action="store_true")
    ap.add_argument("--table", nargs=2, type=Path, metavar=("BEFORE", "NOW"), help="print two runs side by side")
    args = ap.parse_args()
    if args.table:
        rows = {}
        for i, path in enumerate(args.table):
            for line in path.read_text().splitlines():
                r = json.loads(line)
                rows.setdefault((r["case"], r["kind"]), [None, None])[i] = r
        print("| case | kind | before | now |\n|---|---|---|---|")
        for (case, kind), (a, b) in rows.items():
            print(f"| {case} | {kind} | {_cell(a)} | {_cell(b)} |".replace("\n", " "))
        return
    C = cases()
    if args.list:
        print("\n".join(f"{n}: {', '.join(k)}" for n, (k, _) in C.items()))
        return
    names = args.cases.split(",") if args.cases else list(C)
    sink = open(args.out, "w") if args.out else None
    print(f"# tree {args.tree.resolve()}; {os.uname().nodename}; load {os.getloadavg()[0]:.1f}", file=sys.stderr)
    for name in names:
        kinds, build = C[name]
        for kind in kinds:
            if args.kinds and kind not in args.kinds.split(","):
                continue
            r = _run(args.tree.resolve(), name, kind, build)
            print(json.dumps(r), file=sink or sys.stdout, flush=True)
            print(f"{name:28s} {kind:8s} {_cell(r)[:150]}", file=sys.stderr, flush=True)
    if sink:
        sink.close()


if __name__ == "__main__":
    main()
