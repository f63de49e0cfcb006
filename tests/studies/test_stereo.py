"""Refraction-aware binocular reconstruction: round trip, Snell's law, plain triangulation, validation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slipsense.errors import ConfigError, InputError
from studies.stnet.stereo import (
    SensorGeometry,
    camera_to_gel,
    gel_to_camera,
    in_image,
    pixel_rays,
    project,
    reconstruct,
    reconstruct_without_refraction,
    refract,
    refracted_rays,
)

GEOM = SensorGeometry()


def _gel_points(rng, n, geom=GEOM):
    """Points in the gel volume (world frame, mm): the 22 x 21 mm surface, up to 3 mm indented."""
    return np.stack(
        [rng.uniform(-11, 11, n), rng.uniform(-10.5, 10.5, n), geom.h_v_mm + rng.uniform(-3.0, 0.5, n)], axis=1
    )


def test_round_trip_is_exact():
    pts = _gel_points(np.random.default_rng(0), 2000)
    uv_l, uv_r = project(GEOM, pts)
    back, gap = reconstruct(GEOM, uv_l, uv_r, return_gap=True)
    assert np.abs(back - pts).max() < 1e-6
    assert gap.max() < 1e-6
    assert in_image(GEOM, uv_l).all() and in_image(GEOM, uv_r).all()  # the whole gel is seen


def test_plain_triangulation_is_clearly_worse():
    pts = _gel_points(np.random.default_rng(1), 2000)
    uv_l, uv_r = project(GEOM, pts)
    err = np.linalg.norm(reconstruct_without_refraction(GEOM, uv_l, uv_r) - pts, axis=1)
    # measured with the default geometry: 0.92 .. 2.6 mm, mean 1.6 mm; markers look too shallow
    assert err.min() > 0.5 and err.mean() > 1.0
    plain = reconstruct_without_refraction(GEOM, uv_l, uv_r)
    assert (plain[:, 2] < pts[:, 2]).all()


def test_no_refraction_when_indices_match():
    geom = SensorGeometry(n_r=1.0)
    pts = _gel_points(np.random.default_rng(2), 200, geom)
    uv_l, uv_r = project(geom, pts)
    assert np.abs(reconstruct_without_refraction(geom, uv_l, uv_r) - pts).max() < 1e-9


def test_snell_law_holds():
    rng = np.random.default_rng(3)
    d = rng.normal(size=(500, 3))
    d[:, 2] = np.abs(d[:, 2]) + 0.2
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    for n_r in (1.41, 1.0, 0.9):
        normal = np.array([0.0, 0.0, -1.0])  # either orientation is accepted
        if n_r < 1:
            d_ok = d[np.hypot(d[:, 0], d[:, 1]) < n_r * 0.99]
        else:
            d_ok = d
        w = refract(d_ok, normal, n_r)
        np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, atol=1e-12)
        sin1 = np.hypot(d_ok[:, 0], d_ok[:, 1])
        sin2 = np.hypot(w[:, 0], w[:, 1])
        np.testing.assert_allclose(sin1, n_r * sin2, atol=1e-12)
        # refracted ray stays in the plane of incidence and keeps going forward
        np.testing.assert_allclose(d_ok[:, 0] * w[:, 1] - d_ok[:, 1] * w[:, 0], 0.0, atol=1e-12)
        assert (w[:, 2] > 0).all()


def test_total_internal_reflection_is_an_error():
    with pytest.raises(InputError, match="total internal reflection"):
        refract(np.array([[0.8, 0.0, 0.6]]), [0, 0, 1], 0.5)


def test_rays_cross_the_interface_at_eq_1a():
    uv = np.array([[320.0, 240.0], [10.0, 20.0], [600.0, 400.0]])
    origins, e = pixel_rays(GEOM, uv, "left")
    np.testing.assert_allclose(origins, [[-5.0, 0.0, 0.0]] * 3)
    np.testing.assert_allclose(e[0], [0, 0, 1])
    a, w = refracted_rays(GEOM, uv, "right")
    np.testing.assert_allclose(a[:, 2], GEOM.h_v_mm - GEOM.h_c_mm)
    assert (w[:, 2] > e[:, 2] - 1e-12).all()  # bent towards the normal (n_r > 1)


def test_gel_frame_is_a_shift():
    p = np.array([[1.0, 2.0, -0.5]])
    np.testing.assert_allclose(camera_to_gel(GEOM, gel_to_camera(GEOM, p)), p)
    assert gel_to_camera(GEOM, p)[0, 2] == GEOM.h_v_mm - 0.5


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.zeros((3, 3)), "expected"),
        (np.zeros(4), "expected"),
        (np.array([[1.0, np.nan]]), "non-finite"),
        (np.array([[np.inf, 1.0]]), "non-finite"),
        ([["a", "b"]], "numeric"),
    ],
)
def test_bad_pixels_are_input_errors(bad, match):
    with pytest.raises(InputError, match=match):
        reconstruct(GEOM, bad, np.zeros((1, 2)))


def test_mismatched_lengths_and_bad_points():
    with pytest.raises(InputError, match="uv_right has 2"):
        reconstruct(GEOM, np.zeros((1, 2)), np.zeros((2, 2)))
    with pytest.raises(InputError, match="in front of the interface"):
        project(GEOM, np.array([[0.0, 0.0, 5.0]]))
    with pytest.raises(InputError, match="non-finite"):
        project(GEOM, np.array([[0.0, np.nan, 25.0]]))
    with pytest.raises(InputError, match="camera must be"):
        pixel_rays(GEOM, np.zeros((1, 2)), "middle")


def test_parallel_rays_are_reported():
    uv = np.array([[320.0, 240.0]])
    with pytest.raises(InputError, match="near parallel"):
        reconstruct(GEOM, uv, uv)  # zero disparity: the rays never meet
    with pytest.raises(InputError, match="near parallel"):
        reconstruct_without_refraction(GEOM, uv, uv)


def test_swapped_cameras_are_reported():
    uv_l, uv_r = project(GEOM, np.array([[0.0, 0.0, 25.0]]))
    with pytest.raises(InputError, match="swapped"):
        reconstruct(GEOM, uv_r, uv_l)


def test_bad_geometry_is_a_config_error():
    with pytest.raises(ConfigError, match="h_c_mm"):
        SensorGeometry(h_c_mm=30.0)
    with pytest.raises(ConfigError, match="n_r"):
        SensorGeometry(n_r=-1.0)


@settings(max_examples=60, deadline=None)
@given(
    x=st.floats(-11, 11),
    y=st.floats(-10.5, 10.5),
    depth=st.floats(-3.0, 1.0),
    n_r=st.floats(1.0, 1.7),
    h_c=st.floats(1.0, 10.0),
    baseline=st.floats(4.0, 20.0),
)
def test_round_trip_property(x, y, depth, n_r, h_c, baseline):
    geom = SensorGeometry(n_r=n_r, h_c_mm=h_c, baseline_mm=baseline)
    p = np.array([[x, y, geom.h_v_mm + max(depth, -h_c + 0.5)]])
    uv_l, uv_r = project(geom, p)
    assert np.abs(reconstruct(geom, uv_l, uv_r) - p).max() < 1e-6
