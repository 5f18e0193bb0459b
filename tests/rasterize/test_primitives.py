"""Primitives: exact signed distances, spec parsing, bounds (origin = lower bounding-box corner)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from voxflex import InputError
from voxflex.rasterize import Box, Cylinder, Sphere, parse_spec


def test_box_signed_distance_exact():
    box = Box((4, 1, 1), origin=(1, 2, 3))
    pts = np.array([[3, 2.5, 3.5], [1.2, 2.5, 3.5], [6, 2.5, 3.5], [6, 4.5, 3.5], [-1, 0, 1]])
    want = [-0.5, -0.2, 1.0, math.hypot(1.0, 1.5), math.sqrt(4 + 4 + 4)]
    np.testing.assert_allclose(box.signed_distance(pts), want, atol=1e-14)
    lo, hi = box.bounds()
    np.testing.assert_array_equal(lo, [1, 2, 3])
    np.testing.assert_array_equal(hi, [5, 3, 4])


def test_cylinder_signed_distance_and_axis():
    cyl = Cylinder(0.5, 2.0)  # axis z, bounding box [0,1]x[0,1]x[0,2]
    pts = np.array([[0.5, 0.5, 1.0], [0.5, 0.5, 2.5], [1.5, 0.5, 1.0], [1.5, 0.5, 2.5], [0.9, 0.5, 1.9]])
    want = [-0.5, 0.5, 0.5, math.hypot(0.5, 0.5), -0.1]
    np.testing.assert_allclose(cyl.signed_distance(pts), want, atol=1e-14)
    cx = Cylinder(0.5, 2.0, axis="x")
    np.testing.assert_array_equal(cx.bounds()[1], [2, 1, 1])
    np.testing.assert_allclose(cx.signed_distance([[1.0, 0.5, 0.5]]), [-0.5])
    assert cyl.volume == pytest.approx(math.pi * 0.25 * 2)


def test_sphere_signed_distance():
    sph = Sphere(2.0, origin=(-2, -2, -2))  # centred at the origin
    pts = np.array([[0, 0, 0], [3, 0, 0], [0, 1, 0]])
    np.testing.assert_allclose(sph.signed_distance(pts), [-2, 1, -1])


@pytest.mark.parametrize(
    "spec, cls, volume",
    [("box:4,1,1", Box, 4.0), ("cylinder:0.5,2", Cylinder, math.pi / 2), ("sphere:1.5", Sphere, 4.5 * math.pi)],
)
def test_parse_spec(spec, cls, volume):
    prim = parse_spec(spec)
    assert isinstance(prim, cls)
    assert prim.volume == pytest.approx(volume, rel=1e-14)
    np.testing.assert_array_equal(prim.bounds()[0], [0, 0, 0])


@pytest.mark.parametrize(
    "spec, fragment",
    [
        ("box:1,2", "box needs 3"),
        ("sphere:", "sphere needs 1"),
        ("cylinder:1,a", "cylinder needs 2"),
        ("cone:1,2", "unknown primitive 'cone'"),
        ("boxx:1,2,3", "did you mean 'box'"),
        ("sphere:-1", "> 0"),
        ("sphere:nan", "> 0"),
    ],
)
def test_bad_specs_list_the_accepted_forms(spec, fragment):
    with pytest.raises(InputError) as exc:
        parse_spec(spec)
    msg = str(exc.value)
    assert fragment in msg and "\n" not in msg
    if "needs" in fragment or "unknown" in fragment:
        assert "box:LX,LY,LZ" in msg and "sphere:R" in msg


def test_constructor_validation():
    with pytest.raises(InputError):
        Box((1, 0, 1))
    with pytest.raises(InputError):
        Sphere(float("inf"))
    with pytest.raises(InputError, match="valid: x, y, z"):
        Cylinder(1, 1, axis="w")
