import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from roi_network.transform import Rigid2D, wrap_angle

angles = st.floats(-10, 10, allow_nan=False)
coords = st.floats(-1e4, 1e4, allow_nan=False)
transforms = st.builds(Rigid2D, angles, coords, coords)


@given(transforms, transforms, st.lists(st.tuples(coords, coords), min_size=1, max_size=10))
def test_compose_applies_right_then_left(a, b, pts):
    p = np.array(pts)
    np.testing.assert_allclose((a @ b).apply(p), a.apply(b.apply(p)), atol=1e-6)


@given(transforms)
def test_inverse_is_identity(t):
    for ident in (t @ t.inverse(), t.inverse() @ t):
        assert abs(wrap_angle(ident.yaw)) < 1e-9 or abs(abs(ident.yaw) - 2 * math.pi) < 1e-9
        assert abs(ident.tx) < 1e-6 and abs(ident.ty) < 1e-6


@given(transforms)
def test_matrix_round_trip(t):
    back = Rigid2D.from_matrix(t.matrix)
    assert math.isclose(math.cos(back.yaw - t.yaw), 1.0, abs_tol=1e-12)
    np.testing.assert_allclose(back.translation, t.translation, atol=1e-9)


def test_yaw_is_wrapped_and_accessors():
    t = Rigid2D(3 * math.pi / 2, 1.0, 2.0)
    assert math.isclose(t.yaw, -math.pi / 2)
    np.testing.assert_allclose(t.apply([1.0, 0.0]), [1.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(t.translation, [1.0, 2.0])


@given(transforms, st.integers(0, 2**32 - 1))
def test_fit_recovers_exact_transform(t, seed):
    rng = np.random.default_rng(seed)
    src = rng.uniform(-500, 500, size=(rng.integers(2, 30), 2))
    fitted = Rigid2D.fit(src, t.apply(src))
    np.testing.assert_allclose(fitted.apply(src), t.apply(src), atol=1e-6)


def test_fit_weights_follow_heavy_points():
    rng = np.random.default_rng(1)
    src = rng.uniform(-50, 50, size=(20, 2))
    truth = Rigid2D(0.7, 10.0, -3.0)
    dst = truth.apply(src)
    dst[:5] += 30.0  # five gross outliers
    weights = np.r_[np.zeros(5), np.ones(15)]
    fitted = Rigid2D.fit(src, dst, weights)
    np.testing.assert_allclose(fitted.apply(src[5:]), dst[5:], atol=1e-6)
    unweighted = Rigid2D.fit(src, dst)
    assert np.abs(unweighted.apply(src[5:]) - dst[5:]).max() > 1.0


def test_fit_never_reflects():
    rng = np.random.default_rng(2)
    src = rng.uniform(-50, 50, size=(12, 2))
    mirrored = src * [1.0, -1.0]
    fitted = Rigid2D.fit(src, mirrored)
    assert np.linalg.det(fitted.rotation) == pytest.approx(1.0)
    # The best rotation cannot explain a mirror image.
    assert np.abs(fitted.apply(src) - mirrored).max() > 1.0


@pytest.mark.parametrize(
    ("src", "dst", "weights", "match"),
    [
        (np.zeros((1, 2)), np.zeros((1, 2)), None, "at least 2"),
        (np.zeros((3, 2)), np.zeros((4, 2)), None, "must both be"),
        (np.ones((3, 2)), np.ones((3, 2)), None, "coincide"),
        (np.eye(2), np.eye(2), [-1.0, 1.0], "weights"),
    ],
)
def test_fit_rejects_bad_input(src, dst, weights, match):
    with pytest.raises(ValueError, match=match):
        Rigid2D.fit(src, dst, weights)


def test_rejects_non_finite_and_reflection_matrix():
    with pytest.raises(ValueError, match="'tx'"):
        Rigid2D(0.0, float("nan"), 0.0)
    with pytest.raises(ValueError, match="proper rotation"):
        Rigid2D.from_matrix(np.diag([1.0, -1.0, 1.0]))
