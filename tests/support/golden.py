"""Reference values the tests assert, each defined once with where it comes from.

The shared cantilever: beam [0, 4] x [0, 1] x [0, 1], x = 0 clamped, E = 1e4 (linear) or 1e3 (neo-Hooke),
nu = 0.3, rho g = 9.81 along -z, u_z at the tip-face centre (4, 0.5, 0.5).  Trilinear hexahedra with
2x2x2 Gauss points on an nx x nx/4 x nx/4 grid: scikit-fem, warp.fem and sfepy agree on these to six
digits (benchmarks/bench_voxel_model.py prints them side by side); quoted to six significant digits, so
1e-5 relative is their rounding, not slack.
"""

from __future__ import annotations

LINEAR_CANTILEVER_TIP = {8: -0.339310, 16: -0.375726, 32: -0.387621, 64: -0.391219}
"""Linear Hooke (linear strain), E = 1e4: tip u_z (m) per grid nx (nx x nx/4 x nx/4 voxels)."""

LINEAR_CANTILEVER_CONVERGED = -0.39278
"""Linear 3-D converged tip u_z (m), +-1e-4 (NOTES: Euler-Bernoulli -0.376704, Timoshenko -0.400719)."""

NEO_HOOKE_CANTILEVER_TIP_32 = -2.687096
"""Neo-Hooke, E = 1e3, 5 load steps, 32x8x8 voxels: tip u_z (m) of the voxel model (and the peers)."""

NEO_HOOKE_CANTILEVER_CONVERGED = -2.7087
"""Neo-Hooke, E = 1e3: converged tip u_z (m), +-5e-4 (large deflection: linear theory says -3.93)."""

RELATIVE = 1e-5
"""The rounding of the six-digit references above."""
