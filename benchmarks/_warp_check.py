"""Check ``_warp_cantilever.warp_run`` against the agreed cantilever values, optionally time it.

    python benchmarks/_warp_check.py [--timing] [--cold]

Reference tip u_z (6 decimals; scikit-fem, warp.fem and sfepy agree on the linear
ones, voxflex and scikit-fem on the Neo-Hooke one).  ``--timing`` runs
``warp_run(64, 1e4, 0.3, "linear", 1)`` and ``warp_run(32, 1e3, 0.3, "neo-hooke", 5)``
three times each (kernels loaded) and prints every run; ``--cold`` measures the
first-use compile time in a subprocess with an empty warp kernel cache.
"""

import argparse
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

CHECKS = [  # (nx, E, kind, steps, reference u_z)
    (8, 1e4, "linear", 1, -0.339310),
    (16, 1e4, "linear", 1, -0.375726),
    (8, 1e3, "neo-hooke", 5, -2.486996),
]
# the references are given to 6 decimals: agreement means within half a unit of the last digit
TOL = 5e-7


def _row(name, r):
    return (f"| {name} | {r['compile']:.2f} | {r['build']:.3f} | {r['assemble']:.3f} | {r['solve']:.3f} | "
            f"{r['total']:.3f} | {r['newton']} | {r['linear']} | {r['solver']} | {r['uz']:.6f} |")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--timing", action="store_true")
    parser.add_argument("--cold", action="store_true")
    args = parser.parse_args()
    if args.cold:
        with tempfile.TemporaryDirectory() as cache:
            code = ("import time; t = time.perf_counter(); from _warp_cantilever import warp_run; "
                    "i = time.perf_counter() - t; "
                    "a = warp_run(8, 1e4, 0.3, 'linear', 1)['compile']; "
                    "b = warp_run(8, 1e3, 0.3, 'neo-hooke', 1)['compile']; "
                    "print(f'cold cache: import {i:.2f} s, linear first use {a:.2f} s, "
                    "neo-hooke kernels on top {b:.2f} s')")
            env = dict(os.environ, WARP_CACHE_PATH=cache)
            subprocess.run([sys.executable, "-c", code], env=env, check=True,
                           cwd=os.path.dirname(os.path.abspath(__file__)))
    from _warp_cantilever import warp_run

    ok = True
    for nx, young, kind, steps, ref in CHECKS:
        for condense in ("scipy", "project"):  # both ways of clamping give the reference
            r = warp_run(nx, young, 0.3, kind, steps, rtol=1e-10, condense=condense)
            good = abs(r["uz"] - ref) <= TOL
            ok &= good
            print(f"{kind:9s} {nx}x{nx // 4}x{nx // 4} E={young:g} steps={steps} ({condense}): u_z = {r['uz']:.7f} "
                  f"(reference {ref:.6f}, newton {r['newton']}) {'ok' if good else 'MISMATCH'}", flush=True)
    if args.timing:
        print("\n| problem | compile s | build s | assemble s | solve s | total s | newton | linear its | solver | u_z |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for name, call in (("linear 64x16x16", (64, 1e4, 0.3, "linear", 1)),
                           ("neo-hooke E=1e3 32x8x8 5 steps", (32, 1e3, 0.3, "neo-hooke", 5))):
            for _ in range(3):
                print(_row(name, warp_run(*call)), flush=True)
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
