"""Rotation helpers against scipy.spatial.transform.Rotation (the CONVENTIONS interface type)."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nav import rotation as R


@pytest.fixture
def rots():
    return Rotation.random(500, random_state=7)


def test_quat_matrix_against_scipy(rots):
    q = rots.as_quat()  # scalar-last, like ours
    np.testing.assert_allclose(R.quat_to_matrix(q), rots.as_matrix(), atol=1e-14)
    q2 = R.matrix_to_quat(rots.as_matrix())
    # same rotation up to sign
    np.testing.assert_allclose(np.abs(np.sum(q2 * q, axis=-1)), 1.0, atol=1e-14)
    assert np.all(q2[:, 3] >= 0)


def test_matrix_to_quat_near_180_deg():
    r = Rotation.from_rotvec(np.array([[np.pi - 1e-9, 0, 0], [0, np.pi, 0], [0, 0, -np.pi + 1e-12]]))
    q = R.matrix_to_quat(r.as_matrix())
    np.testing.assert_allclose(R.quat_to_matrix(q), r.as_matrix(), atol=1e-14)


def test_products_and_rotvec(rots):
    a, b = rots[:250], rots[250:]
    np.testing.assert_allclose(R.quat_to_matrix(R.quat_multiply(a.as_quat(), b.as_quat())),
                               (a * b).as_matrix(), atol=1e-14)
    phi = rots.as_rotvec()
    np.testing.assert_allclose(R.rotvec_to_matrix(phi), rots.as_matrix(), atol=1e-14)
    np.testing.assert_allclose(R.quat_to_rotvec(rots.as_quat()), phi, atol=1e-12)
    tiny = np.array([1e-9, -2e-9, 3e-10])
    np.testing.assert_allclose(R.rotvec_to_matrix(tiny), Rotation.from_rotvec(tiny).as_matrix(), atol=1e-17)


def test_skew_and_small_angle():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(2, 10, 3))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", R.skew(a), b), np.cross(a, b), atol=1e-15)
    psi = np.array([1e-3, -2e-3, 5e-4])
    R0 = Rotation.random(random_state=1).as_matrix()
    R1 = R.small_angle_update(R0, psi)
    np.testing.assert_allclose(R1, Rotation.from_rotvec(psi).as_matrix() @ R0, atol=1e-15)
    # first order agrees with (I + [psi x]) R to O(|psi|^2) = 5e-6
    assert np.max(np.abs(R1 - (np.eye(3) + R.skew(psi)) @ R0)) < 5e-6


def test_triad_exact_and_degrading():
    rng = np.random.default_rng(11)
    rot = Rotation.random(200, random_state=12)
    v1, v2 = rng.normal(size=(2, 200, 3))
    R_rb = rot.as_matrix()
    b1 = np.einsum("nji,nj->ni", R_rb, v1)  # body = R_rb^T r
    b2 = np.einsum("nji,nj->ni", R_rb, v2)
    est = R.triad(b1, b2, v1, v2, min_angle_deg=0.01)  # noise-free: exact at any angle
    err = np.linalg.norm((Rotation.from_matrix(est) * rot.inv()).as_rotvec(), axis=-1)
    assert err.max() < 1e-12
    # Degrades gracefully: 1 mrad of noise on the secondary vector, shrinking angle between vectors.
    r1 = np.array([0.0, 0.0, 1.0])
    print("TRIAD error vs angle between vectors (1 mrad noise on v2):")
    prev = 0.0
    for ang in [90.0, 30.0, 10.0, 3.0]:
        r2 = np.array([np.sin(np.radians(ang)), 0.0, np.cos(np.radians(ang))])
        noisy = Rotation.from_rotvec([0.0, 1e-3, 0.0]).apply(r2) + np.array([0, 1e-3, 0])
        e = R.triad(r1, noisy, r1, r2)
        err = np.linalg.norm(Rotation.from_matrix(e).as_rotvec())
        print(f"  {ang:5.1f} deg: {np.degrees(err):.4f} deg")
        # about the primary vector the error is ~ noise / sin(angle)
        assert err < 1.5e-3 / np.sin(np.radians(ang)) + 1e-3
        assert err >= prev * 0.99
        prev = err
    with pytest.raises(ValueError, match="from parallel"):
        R.triad(r1, r1 + 1e-4, r1, r1 + [1e-4, 0, 0])


def test_bad_shapes():
    with pytest.raises(ValueError, match="q: expected shape"):
        R.quat_to_matrix(np.zeros(3))
    with pytest.raises(ValueError, match="q: zero-length"):
        R.quat_to_matrix(np.zeros(4))
    with pytest.raises(ValueError, match="R: expected shape"):
        R.matrix_to_quat(np.eye(2))


def test_tangent_basis_is_orthonormal_and_vectorised():
    rng = np.random.default_rng(5)
    e = rng.normal(size=(200, 3))
    e[0] = [1.0, 1e-9, 0.0]  # the switch to the y axis near x
    Tn = R.tangent_bases(e)
    for ei, T in zip(e, Tn):
        u = ei / np.linalg.norm(ei)
        T1 = R.tangent_basis(ei)
        np.testing.assert_allclose(T1, T, atol=1e-15)
        np.testing.assert_allclose(T1.T @ T1, np.eye(2), atol=1e-15)
        np.testing.assert_allclose(T1.T @ u, 0.0, atol=1e-15)
        np.testing.assert_allclose(np.cross(T1[:, 0], T1[:, 1]), u, atol=1e-15)  # right-handed [t1, t2, e]
    with pytest.raises(ValueError, match="e: zero-length"):
        R.tangent_basis(np.zeros(3))
