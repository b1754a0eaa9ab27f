"""Cost of the I&I speed observer (paper 004) per step, and the quadrature's accuracy against scipy quad.

Run: python bench/bench_speed_observer.py   (prints a table; ~10 s on one core)
"""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.integrate import quad

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from agents.speed_observer import ELModel, Gains, SpeedObserver, two_link  # noqa: E402

PAPER = dict(c1=0.9698, c2=0.1575, c3=0.264, c4=1.74, c5=0.44)
OBS0 = ([-8.45, 68.33], [1.0, 2.0], [10.0, 20.0], 0.1)


def per_call_us(fn, repeat: int = 300) -> float:
    fn()
    t0 = time.perf_counter()
    for _ in range(repeat):
        fn()
    return (time.perf_counter() - t0) / repeat * 1e6


def reference_beta(ob: SpeedObserver, y, s_y, s_x) -> np.ndarray:
    """beta (eq. 12) by adaptive scipy quad, one scalar integral per (column, row), split at multiples of pi."""
    out = np.zeros(ob.n)
    for i in range(ob.n):
        def col(t, r, i=i):
            p = np.array(s_y, float)
            p[i] = t
            return ob.H(p, np.asarray(s_x, float))[r, i]

        pts = np.sort(np.r_[0.0, y[i], np.arange(np.ceil(min(0, y[i]) / np.pi), np.floor(max(0, y[i]) / np.pi) + 1) * np.pi])
        for r in range(ob.n):
            out[r] += np.sign(y[i]) * sum(quad(col, a, b, args=(r,), epsabs=1e-14, epsrel=1e-13, limit=200)[0]
                                          for a, b in zip(pts[:-1], pts[1:]))
    return out


def main() -> None:
    warnings.filterwarnings("ignore", message="The occurrence of roundoff")  # quad at 1e-14 asks too much
    model = two_link(**PAPER)
    aper = ELModel(2, model.M, model.C, model.G, model.k_m, model.k_M, model.k_c, model.q_low, model.q_high)
    rng = np.random.default_rng(0)
    cases = [(rng.uniform(-a, a, 2), rng.uniform(-np.pi, np.pi, 2), rng.uniform(-20, 20, 2)) for a in (1.0, 3.0, 10.0, 40.0)]
    print("cost per call, two-link (n = 2), one core:")
    print(f"{'nodes':>6} {'rhs [us]':>10} {'RK4 step [us]':>14}")
    for nodes in (4, 8, 16, 32):
        ob = SpeedObserver(model, Gains(), nodes=nodes)
        obs = ob.initial(*OBS0)
        y, u = np.array([0.4, -2.0]), np.zeros(2)
        st = ob.start(y, *OBS0)
        print(f"{nodes:>6} {per_call_us(lambda: ob.rhs(obs, y, u)):>10.0f} "
              f"{per_call_us(lambda: ob.step(st, y + 1e-3, u, 1e-3), 100):>14.0f}")
    print("\nbeta (eq. 12) accuracy vs scipy.integrate.quad (max abs error / max |beta| over 4 points, |y| up to 40 rad):")
    print(f"{'nodes':>6} {'periodic split':>16} {'plain Gauss-Legendre':>22}")
    refs = [reference_beta(SpeedObserver(model, check=False), *c) for c in cases]
    scale = max(np.abs(r).max() for r in refs)
    for nodes in (4, 8, 16, 32):
        errs = []
        for m in (model, aper):
            ob = SpeedObserver(m, nodes=nodes, check=False)
            errs.append(max(np.abs(ob.beta_terms(*c)[0] - ref).max() for c, ref in zip(cases, refs)) / scale)
        print(f"{nodes:>6} {errs[0]:>16.2e} {errs[1]:>22.2e}")


if __name__ == "__main__":
    main()
