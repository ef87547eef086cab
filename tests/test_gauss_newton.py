"""The fit's step (pipeline.robot.model.gauss_newton): one damped loop over a dense and a normal-equations
evaluator, and the steps on a subset of the poses. Synthetic curve fits."""

import numpy as np
import pytest
import scipy.optimize

from pipeline.robot.model import gauss_newton as gn

T = np.linspace(0.0, 2.0, 40)
Y = 3.0 * np.exp(-1.3 * T) + 0.5 + 0.01 * np.random.default_rng(0).normal(size=T.size)


def fun(z):
    return z[0] * np.exp(-z[1] * T) + z[2] - Y


def fun_and_jac(z):
    e = np.exp(-z[1] * T)
    return fun(z), np.column_stack([e, -z[0] * T * e, np.ones_like(T)])


def normal_equations(z):
    F, J = fun_and_jac(z)
    return F, J.T @ J, J.T @ F


def test_the_dense_loop_reaches_the_least_squares_solution():
    z0 = np.array([1.0, 0.1, 0.0])
    steps = gn.DenseSteps(fun_and_jac, *fun_and_jac(z0), n_penalty=0)
    res = gn.damped_gauss_newton(steps, fun, z0, max_iter=100)
    want = scipy.optimize.least_squares(fun, z0, jac=lambda z: fun_and_jac(z)[1], xtol=1e-15, ftol=1e-15).x
    assert res.converged, res.reason
    np.testing.assert_allclose(res.x, want, rtol=1e-6)
    assert res.cost == pytest.approx(0.5 * float(fun(want) @ fun(want)), rel=1e-9)
    assert steps.dof == pytest.approx(3.0)          # three parameters, no penalty rows: the hat matrix's trace


def test_the_normal_equations_loop_takes_the_dense_loops_steps():
    z0 = np.array([1.0, 0.1, 0.0])
    dense = gn.damped_gauss_newton(gn.DenseSteps(fun_and_jac, *fun_and_jac(z0), 0), fun, z0, 100)
    ne = gn.NormalSteps(normal_equations, *normal_equations(z0))
    on_normal = gn.damped_gauss_newton(ne, fun, z0, 100)
    np.testing.assert_allclose(on_normal.x, dense.x, rtol=1e-8)
    assert on_normal.n_iter == dense.n_iter and on_normal.converged
    assert ne.hat_trace(np.zeros((3, 3))) == pytest.approx(3.0, rel=1e-9)


def test_a_start_already_at_the_solution_that_never_moved_is_not_called_converged():
    z0 = np.array([1.0, 0.1, 0.0])
    z = gn.damped_gauss_newton(gn.DenseSteps(fun_and_jac, *fun_and_jac(z0), 0), fun, z0, 100).x
    again = gn.damped_gauss_newton(gn.DenseSteps(fun_and_jac, *fun_and_jac(z), 0), fun, z, 100)
    assert not again.converged and "never left" in again.reason
    moved = gn.damped_gauss_newton(gn.DenseSteps(fun_and_jac, *fun_and_jac(z), 0), fun, z, 100, moved=True)
    assert moved.converged


def test_a_non_finite_residual_stops_the_loop():
    z0 = np.array([np.nan, 0.1, 0.0])
    res = gn.damped_gauss_newton(gn.DenseSteps(fun_and_jac, *fun_and_jac(z0), 0), fun, z0, 100)
    assert not res.converged and res.reason == "non-finite residual or Jacobian" and res.n_iter == 1


class _LinearDesign:
    """A design whose residual is linear in x: F = A x - y (what a fit's Jacobian is near its solution)."""
    oriented = False

    def __init__(self, A, y):
        self.A, self.y = A, y

    def residual_and_jacobian(self, x):
        return self.A @ x - self.y, self.A


def test_steps_without_some_poses_reach_the_fit_on_the_others():
    rng = np.random.default_rng(3)
    A, y = rng.normal(size=(30, 4)), rng.normal(size=30)
    keep = np.ones(30, bool)
    keep[[2, 17, 25]] = False
    x_all = np.linalg.lstsq(A, y, rcond=None)[0]
    x, rank = gn.steps_without(_LinearDesign(A, y), np.eye(4), np.zeros((0, 4)), x_all, keep.astype(float),
                               sparse=False, measured_mm=None)
    np.testing.assert_allclose(x, np.linalg.lstsq(A[keep], y[keep], rcond=None)[0], rtol=1e-9)
    assert rank == 4
    # in fewer directions (B: the first two parameters only) the steps stay in them
    x2, rank2 = gn.steps_without(_LinearDesign(A, y), np.eye(4)[:, :2], np.zeros((0, 4)), np.zeros(4),
                                 keep.astype(float), sparse=False, measured_mm=None)
    assert rank2 == 2 and np.all(x2[2:] == 0.0)
