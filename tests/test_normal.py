"""The one home of column-scaled normal-equation solves (pipeline.robot.model.normal): Cholesky where
well-conditioned, eigen-directions otherwise, the cut-offs named arguments. Synthetic matrices."""

import numpy as np
import pytest
import scipy.sparse

from pipeline.robot.model import normal


def _problem(seed=0, m=200, k=12, redundant=False):
    rng = np.random.default_rng(seed)
    J = rng.normal(size=(m, k)) * rng.uniform(0.01, 100.0, size=k)
    if redundant:
        J[:, 4] = 2.0 * J[:, 1] - J[:, 2]
    r = rng.normal(size=m)
    return J, r


def test_column_scale_floors_a_zero_diagonal_at_one_or_at_the_floor():
    d = np.array([4.0, 0.0, -1e-20, 9.0])
    np.testing.assert_array_equal(normal.column_scale(d), [2.0, 1.0, 1.0, 3.0])
    np.testing.assert_array_equal(normal.column_scale(d, floor=1e-300), np.sqrt([4.0, 1e-300, 1e-300, 9.0]))


def test_the_min_norm_step_is_the_least_squares_step_of_a_full_rank_jacobian():
    J, r = _problem()
    dz, gain, rank = normal.scaled_min_norm_step(J.T @ J, J.T @ r, with_rank=True)
    want = -np.linalg.lstsq(J, r, rcond=None)[0]
    np.testing.assert_allclose(dz, want, rtol=1e-8, atol=1e-12 * np.abs(want).max())
    assert rank == 12
    # the gain is how much the step changes the residual: ||J dz||^2
    assert gain == pytest.approx(float(np.sum((J @ dz) ** 2)), rel=1e-8)


def test_a_redundant_direction_is_left_out_by_the_eigen_solution():
    J, r = _problem(redundant=True)
    A, b = J.T @ J, J.T @ r
    sc = normal.column_scale(np.diag(A))
    assert normal.well_conditioned_cholesky(A / np.outer(sc, sc)) is None
    y, _, rank = normal.min_norm_solve(A / np.outer(sc, sc), b / sc)
    assert rank == 11
    want = np.linalg.pinv(A / np.outer(sc, sc), rcond=1e-12, hermitian=True) @ (b / sc)
    np.testing.assert_allclose(y, want, rtol=1e-6, atol=1e-9 * np.abs(want).max())


def test_the_cut_off_is_a_named_argument():
    """A weak direction (eigenvalue 1e-9 of the largest) is kept at the fit's 1e-12 and left out at the
    diagnosis's weaker 2.5e-7: the two solutions differ in exactly that direction."""
    V = np.linalg.qr(np.random.default_rng(4).normal(size=(5, 5)))[0]
    ev = np.array([1e-9, 0.1, 0.5, 1.0, 2.0])
    As, bs = (V * ev) @ V.T, V @ np.ones(5)
    strong, _, n_strong = normal.min_norm_solve(As, bs, cholesky=False)
    weak, _, n_weak = normal.min_norm_solve(As, bs, rtol=2.5e-7, floor=1e-300, cholesky=False)
    assert (n_strong, n_weak) == (5, 4)
    np.testing.assert_allclose(V.T @ (strong - weak), [1e9, 0, 0, 0, 0], rtol=1e-4, atol=1e-3)
    P = normal.pseudo_inverse(As, rtol=2.5e-7)
    np.testing.assert_allclose(P @ bs, weak, rtol=1e-10)


def test_the_floor_decides_for_a_matrix_without_a_positive_eigenvalue():
    As = -np.eye(3)
    assert normal.eigen_directions(As)[0].size == 0                   # nothing above 1e-12 x max(-1, 0)
    assert normal.eigen_directions(np.zeros((3, 3)), floor=1e-300)[0].size == 0


def test_singular_directions_of_the_normal_equations_are_the_jacobians():
    J, _ = _problem(seed=2, k=6)
    Js = J / np.linalg.norm(J, axis=0)
    sv, Vt = normal.singular_directions(Js.T @ Js)
    _, sv_d, Vt_d = np.linalg.svd(Js, full_matrices=False)
    np.testing.assert_allclose(sv, sv_d, rtol=1e-10)
    np.testing.assert_allclose(np.abs(Vt @ Vt_d.T), np.eye(6), atol=1e-8)
    assert normal.singular_directions(np.diag([1.0, 1e-30]))[0].size == 1     # below 1e-12 of the largest


def test_gram_of_a_sparse_jacobian_is_the_dense_products():
    J, r = _problem(seed=5, m=300, k=8)
    sparse = np.array([0, 0, 1, 1, 1, 1, 0, 1], bool)            # most rows zero in these columns
    J[:, sparse] *= np.random.default_rng(1).random((300, int(sparse.sum()))) < 0.1
    H, g = normal.gram(scipy.sparse.csc_matrix(J), r)
    np.testing.assert_allclose(H, J.T @ J, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(g, J.T @ r, rtol=1e-12, atol=1e-9)


def test_the_two_damped_factors_solve_the_damped_equations():
    J, r = _problem(seed=6, k=5)
    A, b = J.T @ J, J.T @ r
    want = np.linalg.solve(A + 3.0 * np.eye(5), b)
    for factor in (normal.damped_cholesky(A, 3.0), normal.levenberg_cholesky(A, 3.0)):
        np.testing.assert_allclose(normal.cholesky_solve(factor, b), want, rtol=1e-9)
    assert normal.damped_cholesky(A, 3.0)[1] is True and normal.levenberg_cholesky(A, 3.0)[1] is False
