"""The analysis's one damped least-squares solver against closed forms."""

import numpy as np
import pytest

from nmsid.analysis.damped_lstsq import Damping, levenberg_marquardt


def _linear(A, b):
    def evaluate(x):
        r = A @ x - b
        return float(r @ r), r

    def normal(x, r):
        return A.T @ A, A.T @ r
    return evaluate, normal


def test_a_linear_problem_lands_on_the_normal_equations_solution():
    rng = np.random.default_rng(3)
    A, b = rng.standard_normal((40, 4)), rng.standard_normal(40)
    res = levenberg_marquardt(*_linear(A, b), np.zeros(4), max_iter=100)
    assert res.converged
    np.testing.assert_allclose(res.x, np.linalg.lstsq(A, b, rcond=None)[0], rtol=1e-6)


def test_a_bound_holds_and_the_free_parameter_is_optimal_given_it():
    # min (x0 - 3)^2 + (x1 - x0)^2 with x0 <= 1: x0 = 1 (at the bound), x1 = 1
    A = np.array([[1.0, 0.0], [-1.0, 1.0]])
    b = np.array([3.0, 0.0])
    res = levenberg_marquardt(*_linear(A, b), np.zeros(2), lo=np.array([-5.0, -5.0]),
                              hi=np.array([1.0, 5.0]), max_iter=100)
    assert res.x[0] == 1.0
    assert res.x[1] == pytest.approx(1.0, abs=1e-6)


def test_rosenbrock_valley_is_followed_to_its_minimum():
    def evaluate(x):
        r = np.array([10 * (x[1] - x[0] ** 2), 1 - x[0]])
        return float(r @ r), r

    def normal(x, r):
        J = np.array([[-20 * x[0], 10.0], [-1.0, 0.0]])
        return J.T @ J, J.T @ r
    res = levenberg_marquardt(evaluate, normal, np.array([-1.2, 1.0]), max_iter=200,
                              damping=Damping(step_tol=1e-12, rel_tol=0.0))
    np.testing.assert_allclose(res.x, [1.0, 1.0], atol=1e-8)


def test_a_refused_start_region_and_a_stall_are_reported():
    def evaluate(x):       # every point but the start is refused
        return (1.0, None) if x[0] == 0.0 else (np.inf, None)

    res = levenberg_marquardt(evaluate, lambda x, s: (np.eye(1), np.ones(1)), np.zeros(1),
                              stalled_converged=lambda H, g, c: False)
    assert res.stalled and not res.converged and "no step decreases" in res.message
