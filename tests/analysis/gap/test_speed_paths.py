"""The fit's speed paths give the answer of the plain computation they replace (issue 30,
item 5): the drive kept across a Jacobian's per-level perturbations, the per-level ``Kp``
and normal equations summed by level in one pass, and ``nmsid gap``'s single BLAS thread."""

import os
import subprocess
import sys

import numpy as np
import pytest

from nmsid.analysis.gap.data import load_session
from nmsid.analysis.gap.fit import Problem, _normal_equations, initial_levels
from nmsid.analysis.gap.models import NOMINAL, candidate
from nmsid.protocols.effects import Effect


@pytest.fixture(scope="module")
def data(nominal_session):
    return load_session(nominal_session)


def test_drive_is_computed_once_per_shared_parameters(data, monkeypatch):
    cand = candidate(Effect.DEAD_TIME)
    prob = Problem(data, cand)
    calls = []
    real = type(cand).drive

    def counting(self, d, p):
        calls.append(np.array(p))
        return real(self, d, p)

    monkeypatch.setattr(type(cand), "drive", counting)
    wn, zeta = initial_levels(data)
    p = np.array([np.log(0.02), 0.0])
    r1, _ = prob.residual(wn, zeta, p)
    r2, _ = prob.residual(wn * 1.01, zeta, p)       # a wn perturbation: same drive
    assert len(calls) == 1
    r3, _ = prob.residual(wn, zeta, p + [0.1, 0.0])  # a shared parameter moved: new drive
    assert len(calls) == 2
    # and the kept drive is the right one: back to p gives r1 again
    np.testing.assert_array_equal(prob.residual(wn, zeta, p)[0], r1)
    assert not np.allclose(r2, r1) and not np.allclose(r3, r1)


def test_kp_per_level_is_the_closed_form_least_squares(data):
    prob = Problem(data, NOMINAL)
    wn, zeta = initial_levels(data)
    p = np.zeros(1)
    r, Kp = prob.residual(wn, zeta, p)
    xp = prob.project(prob.unit_response(wn, zeta, p))
    for k, rows in enumerate(prob.rows):
        want = np.sum(xp[rows] * prob.yp[rows]) / np.sum(xp[rows] ** 2)
        assert Kp[k] == pytest.approx(want, rel=1e-12)
        np.testing.assert_allclose(r[rows], prob.yp[rows] - want * xp[rows], atol=1e-12)


def test_normal_equations_equal_the_dense_jacobian(data):
    """``J^T J`` and ``J^T r`` summed per level equal those of the full forward-difference
    Jacobian built column by column."""
    cand = candidate(Effect.ACTIVATION_DYNAMICS)
    prob = Problem(data, cand)
    nL = len(prob.levels)
    wn, zeta = initial_levels(data)
    x = np.concatenate([np.log(wn), np.log(zeta), [np.log(0.02), 0.1]])

    def fun(v):
        return prob.residual(np.exp(v[:nL]), np.exp(v[nL:2 * nL]), v[2 * nL:])[0]

    r0 = fun(x)
    H, g = _normal_equations(fun, x, r0, prob.rows, nL, 2)
    step = 1e-4
    J = np.empty((r0.size, x.size))
    for i in range(x.size):
        xs = x.copy()
        xs[i] += step
        J[:, i] = ((fun(xs) - r0) / step).ravel()
    np.testing.assert_allclose(H, J.T @ J, rtol=1e-9, atol=1e-9 * np.abs(J.T @ J).max())
    np.testing.assert_allclose(g, J.T @ r0.ravel(), rtol=1e-9,
                               atol=1e-9 * np.abs(J.T @ r0.ravel()).max())


@pytest.mark.parametrize("preset, want", [(None, "1"), ("3", "3")])
def test_gap_command_keeps_blas_single_threaded_unless_the_user_says(preset, want, tmp_path):
    # through the CLI's one switch (nmsid.cli.SINGLE_THREAD_COMMANDS), set before the
    # handler imports numpy; a missing session ends the command with exit 2 after that
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if preset is not None:
        env["OPENBLAS_NUM_THREADS"] = preset
    code = ("import os, sys\nfrom nmsid.cli import main\n"
            f"rc = main(['gap', {str(tmp_path / 'missing.h5')!r}, '--out', "
            f"{str(tmp_path / 'out')!r}])\n"
            "print(rc, os.environ['OPENBLAS_NUM_THREADS'])")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True)
    assert out.stdout.split()[-2:] == ["2", want]
