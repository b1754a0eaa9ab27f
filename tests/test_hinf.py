"""Cooperative H-infinity estimator design (paper 003): spec errors, Prop. 2, LMIs (6)-(7), checks."""
from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as sla

from hinf import SpecError, design_cli, load_spec, parse_spec
from hinf import design as D

EXAMPLE = Path(__file__).resolve().parents[1] / "config" / "hinf" / "sec5-cyclic.toml"
warnings.filterwarnings("ignore", message="Solution may be inaccurate")


def _agent(name, A, C=((1.0, 0.0),), Bt=((0.0,), (0.5,))):
    return {"name": name, "A": [list(r) for r in A], "Bt": [list(r) for r in Bt], "C": [list(r) for r in C]}


@pytest.fixture(scope="module")
def example():
    spec = load_spec(EXAMPLE)
    net = D.network_from_spec(spec)
    return spec, net, D.design_estimators(net)


def test_spec_errors_name_file_and_field(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(EXAMPLE.read_text().replace("A = [[0.1, 1.0], [0.0, -1.0]]", "A = [[0.1, 1.0]]"))
    with pytest.raises(SpecError) as exc:
        load_spec(bad)
    msg = str(exc.value)
    assert str(bad) in msg and "agents[2:3]" in msg and "A must be square" in msg

    data = json.loads(json.dumps({"omega": -1, "agents": [_agent("x", [[0, 1], [0, 0]])], "edges": [["x", "y"]]}))
    with pytest.raises(SpecError) as exc:
        parse_spec(data, "s.json")
    assert "s.json: omega:" in str(exc.value)
    data["omega"] = 0.1
    with pytest.raises(SpecError, match="unknown agent 'y'"):
        parse_spec(data)
    data["edges"] = []
    data["agents"][0]["C"] = [[1.0, 0.0, 0.0]]
    with pytest.raises(SpecError, match=r"agents\[0:x\]: .*C must have 2 columns"):
        parse_spec(data)
    syn = tmp_path / "syn.toml"
    syn.write_text("omega = [")
    with pytest.raises(SpecError, match="syntax error"):
        load_spec(syn)


def test_example_is_detectable_and_feasible(example):
    _, net, est = example
    assert [c.detectable for c in D.check_detectability(net)] == [True]
    assert est.status == "optimal" and 1.0 < est.gamma < 50.0


def test_realised_norm_below_gamma(example):
    _, net, est = example
    es = D.error_system(net, est)
    norm, _ = D.hinf_norm(es.A, es.B, es.C)
    assert norm <= est.gamma * (1 + 1e-6)


def test_error_decays_at_rate_alpha(example):
    """V = sum e^(k)' P^(k) e^(k) must satisfy V(t) <= exp(-alpha t) V(0) without disturbances."""
    _, net, est = example
    es = D.error_system(net, est)
    P = sla.block_diag(*[g.P for g in est.gains])
    rng = np.random.default_rng(3)
    ts = np.linspace(0, 40, 81)
    for _ in range(5):
        e0 = rng.normal(size=es.A.shape[0])
        V0 = e0 @ P @ e0
        for t in ts:
            e = sla.expm(es.A * t) @ e0
            assert e @ P @ e <= np.exp(-net.alpha * t) * V0 * (1 + 1e-6) + 1e-12


def test_fixed_gamma_feasible_above_and_infeasible_below(example):
    _, net, est = example
    D.design_estimators(net, gamma=est.gamma * 1.05)
    with pytest.raises(D.InfeasibleError, match="infeasible at gamma=1"):
        D.design_estimators(net, gamma=1.0)


def test_too_fast_decay_is_infeasible(example):
    spec, _, _ = example
    net = D.network_from_spec(spec.model_copy(update={"alpha": 50.0}))
    with pytest.raises(D.InfeasibleError):
        D.design_estimators(net)


def test_undetectable_component_refused_with_its_name():
    """Two identical double integrators see only y2 - y1: the common mode is invisible."""
    di = [[0, 1], [0, 0]]
    data = {"omega": 0.1, "alpha": 0.1,
            "agents": [_agent("a", di), _agent("b", di), _agent("c", [[-1, 0], [0, -2]])],
            "edges": [["a", "b"], ["b", "a"], ["a", "c"]]}
    net = D.network_from_spec(parse_spec(data))
    checks = D.check_detectability(net)
    assert [(c.agents, c.detectable) for c in checks] == [(["a", "b"], False)]
    with pytest.raises(D.UndetectableError, match=r"\{a, b\}.*eigenvalue\(s\): 0") as exc:
        D.design_estimators(net)
    assert exc.value.component == ["a", "b"]


def test_unstable_leader_without_measurements_refused():
    data = {"omega": 0.1, "agents": [_agent("lead", [[0.5, 0], [0, -1]]), _agent("f", [[-1, 1], [0, -1]])],
            "edges": [["lead", "f"]]}
    with pytest.raises(D.UndetectableError, match=r"\{lead\}"):
        D.design_estimators(D.network_from_spec(parse_spec(data)))


def test_heterogeneity_makes_pair_detectable():
    data = {"omega": 0.1, "alpha": 0.05,
            "agents": [_agent("a", [[0, 1], [0, 0]]), _agent("b", [[-1, 0], [0, -2]])],
            "edges": [["a", "b"], ["b", "a"]]}
    net = D.network_from_spec(parse_spec(data))
    est = D.design_estimators(net)
    es = D.error_system(net, est)
    assert D.hinf_norm(es.A, es.B, es.C)[0] <= est.gamma * (1 + 1e-6)


def test_centralized_yardstick_is_realisable(example):
    _, net, _ = example
    g = D.centralized_bound(net)
    assert 1.0 < g < 100.0


def test_hinf_norm_matches_first_order_system():
    A, B, C = np.array([[-2.0]]), np.array([[1.0]]), np.array([[3.0]])
    assert D.hinf_norm(A, B, C)[0] == pytest.approx(1.5, rel=1e-9)


def test_design_cli_writes_json(tmp_path):
    out = tmp_path / "gains.json"
    res = design_cli(EXAMPLE, out)
    back = json.loads(out.read_text())
    assert back["gamma"] == pytest.approx(res["gamma"])
    assert back["realised_norm"] <= back["gamma"]
    assert [g["tracks"] for g in back["gains"]] == [["1", "2"], ["2", "3"], ["3", "4"], ["4", "1"]]
    assert "kappa" in back["sync"]


@pytest.mark.slow
def test_random_ring_20_design_and_norm():
    from hinf.spec import random_ring_spec

    net = D.network_from_spec(parse_spec(random_ring_spec(20, np.random.default_rng(2))))
    est = D.design_estimators(net)
    es = D.error_system(net, est)
    assert D.hinf_norm(es.A, es.B, es.C)[0] <= est.gamma * (1 + 1e-6)
