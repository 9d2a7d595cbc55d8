"""Rotation conventions and TUM trajectory files."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ifmi.errors import InputError
from ifmi.io.tum import Trajectory, read_tum, write_tum
from ifmi.geometry.rotations import (
    cross,
    geodesic_angle,
    matrix_aligning_rays,
    matrix_from_quat_xyzw,
    matrix_from_rpy,
    project_to_rotation,
    quat_xyzw_from_matrix,
    rpy_from_matrix,
    wrap_angle,
)


def test_rpy_is_scipy_zyx_read_as_yaw_pitch_roll():
    rng = np.random.default_rng(3)
    R = Rotation.random(50, random_state=rng).as_matrix()
    ypr = Rotation.from_matrix(R).as_euler("ZYX")
    np.testing.assert_allclose(rpy_from_matrix(R), ypr[:, ::-1], atol=1e-12)


def test_rpy_axes():
    """Yaw turns about z, pitch about y, roll about x."""
    a = 0.3
    np.testing.assert_allclose(matrix_from_rpy(np.array([0, 0, a])) @ [1, 0, 0],
                               [np.cos(a), np.sin(a), 0], atol=1e-12)
    np.testing.assert_allclose(matrix_from_rpy(np.array([0, a, 0])) @ [0, 0, 1],
                               [np.sin(a), 0, np.cos(a)], atol=1e-12)
    np.testing.assert_allclose(matrix_from_rpy(np.array([a, 0, 0])) @ [0, 1, 0],
                               [0, np.cos(a), np.sin(a)], atol=1e-12)


def test_rpy_round_trip():
    rng = np.random.default_rng(4)
    rpy = rng.uniform([-np.pi, -1.5, -np.pi], [np.pi, 1.5, np.pi], (100, 3))
    np.testing.assert_allclose(rpy_from_matrix(matrix_from_rpy(rpy)), rpy, atol=1e-10)


def test_quaternion_round_trip_and_sign():
    rng = np.random.default_rng(5)
    R = Rotation.random(30, random_state=rng).as_matrix()
    q = quat_xyzw_from_matrix(R)
    assert np.all(q[:, 3] >= 0)
    np.testing.assert_allclose(matrix_from_quat_xyzw(q), R, atol=1e-12)


def test_geodesic_angle_small_and_large():
    for angle in (1e-9, 1e-4, 0.5, 3.0):
        R = Rotation.from_rotvec([0.0, angle, 0.0]).as_matrix()
        assert geodesic_angle(np.eye(3), R) == pytest.approx(angle, rel=1e-9, abs=1e-15)


def test_wrap_angle():
    np.testing.assert_allclose(wrap_angle(np.array([3 * np.pi / 2, -3 * np.pi / 2, 0.1])),
                               [-np.pi / 2, np.pi / 2, 0.1])


def test_project_to_rotation():
    rng = np.random.default_rng(6)
    R = Rotation.random(random_state=rng).as_matrix()
    P = project_to_rotation(R + 1e-3 * rng.standard_normal((3, 3)))
    np.testing.assert_allclose(P @ P.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(P) == pytest.approx(1.0)
    assert geodesic_angle(R, P) < 1e-2


def test_matrix_aligning_rays_is_the_smallest_turn_between_them():
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(2, 50, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    R = matrix_aligning_rays(a, b)
    assert np.allclose(np.einsum("nij,nj->ni", R, a), b, atol=1e-12)
    assert np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3), atol=1e-12) and np.allclose(np.linalg.det(R), 1.0)
    # Smallest: its angle is the angle between the rays, about an axis normal to both.
    between = np.arccos(np.clip(np.einsum("ni,ni->n", a, b), -1, 1))
    rotvec = Rotation.from_matrix(R).as_rotvec()
    assert np.allclose(np.linalg.norm(rotvec, axis=1), between, atol=1e-9)
    assert np.allclose(np.einsum("ni,ni->n", rotvec, a), 0.0, atol=1e-9)
    assert np.allclose(matrix_aligning_rays(a, a), np.eye(3), atol=1e-15)
    # A fraction turns about the same axis by that part of the angle.
    half = Rotation.from_matrix(matrix_aligning_rays(a, b, fraction=0.5)).as_rotvec()
    assert np.allclose(half, rotvec / 2, atol=1e-12)


def test_cross_equals_numpy_cross_bit_for_bit_with_broadcasting():
    rng = np.random.default_rng(5)
    u = rng.normal(size=(4, 7, 3))
    v = rng.normal(size=(7, 3))
    assert np.array_equal(cross(u, v), np.cross(u, v))
    assert np.array_equal(cross(u[0, 0], v[0]), np.cross(u[0, 0], v[0]))


def test_tum_round_trip(tmp_path):
    rng = np.random.default_rng(8)
    n = 12
    traj = Trajectory(timestamps=np.arange(n, dtype=float), positions=rng.standard_normal((n, 3)),
                      rotations=Rotation.random(n, random_state=rng).as_matrix())
    path = tmp_path / "traj.txt"
    write_tum(path, traj, header="made by a test\nsecond line")
    back = read_tum(path)
    np.testing.assert_allclose(back.timestamps, traj.timestamps)
    np.testing.assert_allclose(back.positions, traj.positions, atol=1e-9)
    np.testing.assert_allclose(back.rotations, traj.rotations, atol=1e-11)
    assert path.read_text().startswith("# made by a test\n# second line\n")


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("0 0 0 0 0 0 0\n", "line 1: expected 8 values"),
        ("# c\n0 0 0 0 0 0 0 x\n", "line 2: non-numeric value"),
        ("1_0 0 0 0 0 0 0 1\n", "line 1: non-numeric value"),  # float() would read 10
        ("0 0 0 0 0 0 0 0\n", "line 1: zero quaternion"),
        ("0 0 0 nan 0 0 0 1\n", "line 1: non-finite value"),
        # Positions and quaternion swapped (t qx qy qz qw tx ty tz): the norm gives it away.
        ("0 0 0 0 1 0.5 1.5 -2\n", "line 1: quaternion .* of norm 2.739, expected 1 within 0.01"),
        ("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1.0101\n", "line 2: quaternion .* of norm 1.01"),
        ("# only a comment\n", "no poses"),
    ],
)
def test_malformed_tum(tmp_path, content, message):
    path = tmp_path / "bad.txt"
    path.write_text(content)
    with pytest.raises(InputError, match=message) as info:
        read_tum(path)
    assert str(path) in str(info.value)


def test_identity_in_w_x_y_z_order_warns(tmp_path):
    from ifmi.errors import InputWarning

    path = tmp_path / "wxyz.txt"
    path.write_text("# t tx ty tz qw qx qy qz\n0 0 0 0 1 0 0 0\n1 0.1 0 0 0.999 0 0 0.0447\n")
    with pytest.warns(InputWarning, match=r"wxyz.txt: line 2: the first pose reads as a half turn about x"):
        read_tum(path)
    path.write_text("0 0 0 0 0 0 0 1\n1 0 0 0 1 0 0 0\n")  # a half turn later on is a pose like any other
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_tum(path)


def test_missing_tum(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_tum(tmp_path / "missing.txt")
