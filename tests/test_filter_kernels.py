"""The filter bank's row kernels (agents/kernels/filter.py): compiled equals the same source interpreted
(``py_func``) bit for bit on filter runs that pass every branch, a slot's result does not depend on the
bank it is in (batch of one == batch of n, rows of different dimension and branches side by side), and
the view's copy is independent of its original."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from agents.kernels import filter as F
from agents.rigid_filter import RigidEKF, init_slot
from config.agent_params import DynamicsSpec

SPECS = {
    "nominal": DynamicsSpec(),
    "background": DynamicsSpec(algorithm="sequential", estimate_effects=("viscous_friction", "coulomb_friction")),
    "detection": DynamicsSpec(algorithm="sequential", online_detection=True),
}


def _script(rng: np.random.Generator, n: int) -> list[tuple]:
    """A filter's calls: start, then predict/update pairs (delayed, missing and current rates), the releases,
    forget_iota, hold_shape and the omega walk at fixed points; a restart in the middle."""
    calls: list[tuple] = [("start", complex(*rng.normal(0, 0.3, 2)), complex(*rng.normal(1.0, 0.5, 2)), 0.4)]
    for t in range(n):
        force = complex(*rng.normal(0, 50, 2))
        calls.append(("predict", force, float(rng.normal(0, 10)), 0.01, complex(*rng.normal(0, 2, 2))))
        u = float(rng.normal(0.4, 0.05)) if t % 5 else math.nan
        dc, dw = (float(rng.normal(0, 0.01)), float(rng.normal(0, 0.01))) if t % 3 == 0 else (0.0, 0.0)
        calls.append(("update", complex(*rng.normal(0, 0.5, 2)), u, 0.01 * (t % 4), dc, dw))
        if t == n // 5:
            calls.append(("release_effects",))
        if t == n // 4:
            calls.append(("release_effect", 3))
        if t == n // 3:
            calls += [("forget_iota", 1e-2), ("set_omega_walk", 0.005), ("release_effect", 1)]
        if t == n // 2:
            calls.append(("start", complex(0.1, -0.2), complex(1.2, 0.3), -0.2))
        if t == 3 * n // 4:
            calls += [("hold_shape",), ("release_effect", 0)]
    return calls


def _run(kernels: dict, bank: tuple, b: int, k: int, calls: list[tuple]) -> None:
    fs, s, P, sens, Qd, aug, innov, sens_h = bank
    for name, *a in calls:
        if name == "start":
            kernels["start"](fs, s, P, sens, b, k, *a)
        elif name == "predict":
            kernels["predict"](fs, s, P, sens, Qd, aug, b, k, *a)
        elif name == "update":
            kernels["update"](fs, s, P, sens, innov, sens_h, b, k, *a)
        elif name == "release_effects":
            kernels["release_effects"](fs, s, P, aug, b, k)
        elif name == "release_effect":
            kernels["release_effect"](fs, s, P, aug, b, k, *a)
        elif name == "forget_iota":
            kernels["forget_iota"](fs, P, b, k, *a)
        elif name == "hold_shape":
            kernels["hold_shape"](fs, s, P, Qd, b, k)
        else:
            kernels["set_omega_walk"](Qd, b, k, *a)


KERNELS = {"start": F.ekf_start, "predict": F.ekf_predict, "update": F.ekf_update,
           "release_effects": F.ekf_release_effects, "release_effect": F.ekf_release_effect,
           "forget_iota": F.ekf_forget_iota, "hold_shape": F.ekf_hold_shape, "set_omega_walk": F.ekf_set_omega_walk}


def _bank(names: list[str], slots: int = 1) -> tuple:
    bank = F.new_bank(len(names), slots, F.D_AUGMENTED)
    for b, name in enumerate(names):
        for k in range(slots):
            init_slot(bank, b, k, 0.1, SPECS[name], name == "background")
    return bank


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.tobytes() == b.tobytes()


@pytest.mark.parametrize("name", sorted(SPECS))
def test_compiled_equals_interpreted_bit_for_bit(name):
    calls = _script(np.random.default_rng(4), 120)
    compiled, interpreted = _bank([name]), _bank([name])
    _run(KERNELS, compiled, 0, 0, calls)
    _run({k: f.py_func for k, f in KERNELS.items()}, interpreted, 0, 0, calls)
    for a, b in zip(compiled, interpreted):
        assert _same_bits(a, b)
    assert compiled[0][0, 0]["ready"] and np.all(np.isfinite(compiled[2]))


def test_coulomb_sat_compiled_equals_interpreted():
    rng = np.random.default_rng(2)
    for vx, vy in [*rng.normal(0, 0.2, (200, 2)), (0.0, 0.0), (1e-14, -1e-14)]:
        assert F.coulomb_sat(vx, vy, 0.05) == F.coulomb_sat.py_func(vx, vy, 0.05)


def test_a_slot_gives_the_same_bits_in_any_bank():
    """Three agents of different models (d 8 and 13, sensitivities on or off), two slots each, each slot with
    its own calls: every slot equals the same calls on a bank of one."""
    names = ["nominal", "detection", "background"]
    scripts = [[_script(np.random.default_rng(10 * b + k), 60) for k in range(2)] for b in range(3)]
    bank = _bank(names, 2)
    for b in range(3):
        for k in range(2):
            _run(KERNELS, bank, b, k, scripts[b][k])
    for b, name in enumerate(names):
        for k in range(2):
            one = _bank([name])
            _run(KERNELS, one, 0, 0, scripts[b][k])
            for a, o in zip(bank, one):
                assert _same_bits(np.ascontiguousarray(a[b, k]), np.ascontiguousarray(o[0, 0]))


def test_copy_slot_and_the_views_copy_are_independent():
    bank = _bank(["detection"], 2)
    _run(KERNELS, bank, 0, 0, _script(np.random.default_rng(1), 30))
    F.ekf_copy_slot(*bank, 0, 0, 1)
    for a in bank:
        assert _same_bits(np.ascontiguousarray(a[0, 0]), np.ascontiguousarray(a[0, 1]))
    kf = RigidEKF(0.1, SPECS["detection"], False)
    kf.start(0.1 + 0.2j, 1.0 + 0.5j, 0.3)
    twin = copy.copy(kf)
    s, P = kf.s, kf.P
    twin.predict(40 + 10j, 3.0, 0.01)
    twin.update(0.2 + 0.1j, 0.35, 0.01)
    assert _same_bits(kf.s, s) and _same_bits(kf.P, P)  # the original did not move
    assert not _same_bits(twin.s, s)
    held = kf.s
    kf.predict(40 + 10j, 3.0, 0.01)
    assert _same_bits(held, s)  # a caller's s is a copy
