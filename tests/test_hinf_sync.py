"""Theorem 3 for the Sec. 5 example: Francis equations (12), Riccati (14), weights (15)."""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from hinf import load_spec
from hinf import design as D

EXAMPLE = Path(__file__).resolve().parents[1] / "config" / "hinf" / "sec5-cyclic.toml"
warnings.filterwarnings("ignore", message="Solution may be inaccurate")


def test_printed_S_is_a_misprint():
    """The printed S = [[0,0],[0,1]] fails (12) with the printed Pi_k, Lambda_k; [[0,1],[0,0]] solves it."""
    spec = load_spec(EXAMPLE)
    net = D.network_from_spec(spec)
    G = np.array(spec.sync.Gamma)
    printed, fixed = np.array([[0.0, 0.0], [0.0, 1.0]]), np.array(spec.sync.S)
    for k, a in enumerate(spec.agents):
        args = (net.A[k], net.B[k], net.C[k], np.array(a.Pi), np.array(a.Lambda))
        assert D.francis_residual(*args, fixed, G) < 1e-12
        assert D.francis_residual(*args, printed, G) >= 1.0
    assert np.linalg.eigvals(printed).real.max() == 1.0  # violates sigma(S) on jR of Theorem 3


def test_solve_francis_recovers_printed_pi_lambda():
    spec = load_spec(EXAMPLE)
    net = D.network_from_spec(spec)
    for k, a in enumerate(spec.agents):
        Pi, Lam, res = D.solve_francis(net.A[k], net.B[k], net.C[k], np.array(spec.sync.S), np.array(spec.sync.Gamma))
        assert res < 1e-10
        np.testing.assert_allclose(Pi, a.Pi, atol=1e-10)
        np.testing.assert_allclose(Lam, a.Lambda, atol=1e-10)


def test_riccati_and_bounds():
    spec = load_spec(EXAMPLE)
    net = D.network_from_spec(spec)
    sd = D.design_sync(net, spec)
    for k in range(net.N):
        A, B = net.A[k], net.B[k]
        assert np.linalg.eigvalsh(sd.X[k]).min() > 0
        assert np.linalg.eigvals(A + B @ sd.H[k]).real.max() < 0
    assert sd.kappa == pytest.approx(np.sqrt(1.2**2 + 1 * sd.gamma**2))
    assert sd.theta == sd.gamma
