"""The hot-path rewrites of the kinematic estimators compute exactly (bit for bit) what the plain code does.

Reference implementations of the textbook forms live here: the unrolled 3x3 solver against the
pivoting loop, the deferred circle-fit moments against per-point accumulation, and the pair
estimator's lazily folded window against a per-sample ``CircleSums.add`` and checkpoint list.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from agents.geometry import CircleSums, solve3
from agents.pair_estimator import PairEstimator
from config.agent_params import EstimatorSpec


def _solve3_loop(a: list[list[float]], b: list[float]) -> tuple[float, float, float] | None:
    """The textbook Gaussian elimination with partial pivoting (the former implementation)."""
    m = [a[0][:] + [b[0]], a[1][:] + [b[1]], a[2][:] + [b[2]]]
    scale = max(abs(v) for row in a for v in row) or 1.0
    for c in range(3):
        p = max(range(c, 3), key=lambda r: abs(m[r][c]))
        if abs(m[p][c]) <= 1e-13 * scale:
            return None
        if p != c:
            m[c], m[p] = m[p], m[c]
        piv = m[c][c]
        for r in range(c + 1, 3):
            f = m[r][c] / piv
            if f != 0.0:
                for k in range(c, 4):
                    m[r][k] -= f * m[c][k]
    x2 = m[2][3] / m[2][2]
    x1 = (m[1][3] - m[1][2] * x2) / m[1][1]
    x0 = (m[0][3] - m[0][1] * x1 - m[0][2] * x2) / m[0][0]
    return x0, x1, x2


def _outcome(fn, a, b):  # type: ignore[no-untyped-def]
    try:
        return repr(fn(a, b))
    except ZeroDivisionError:
        return "ZeroDivisionError"


@pytest.mark.parametrize("kind", ["gauss", "special", "small-int"])
def test_unrolled_solve3_is_bit_identical_to_the_loop(kind: str) -> None:
    rng = np.random.default_rng(7)
    special = [0.0, -0.0, 1.0, -1.0, 1e-14, 2.0, 3.0, math.nan, math.inf]
    for _ in range(20_000):
        if kind == "gauss":
            vals = rng.normal(size=12).tolist()
        elif kind == "special":
            vals = [special[i] for i in rng.integers(0, len(special), 12)]
        else:
            vals = rng.integers(-2, 3, 12).astype(float).tolist()
        a = [vals[0:3], vals[3:6], vals[6:9]]
        b = vals[9:12]
        assert _outcome(solve3, a, b) == _outcome(_solve3_loop, a, b), (a, b)


def test_circle_sums_extend_equals_add() -> None:
    rng = np.random.default_rng(3)
    pts = [complex(x, y) for x, y in rng.normal(size=(500, 2)) * 3.0]
    one, many = CircleSums(), CircleSums()
    for p in pts:
        one.add(p)
    many.extend(pts[:123])
    many.extend(pts, 123)
    names = CircleSums.__slots__
    assert [getattr(one, s) for s in names] == [getattr(many, s) for s in names]
    assert repr(one.fit()) == repr(many.fit())


class _ReferencePair(PairEstimator):
    """The former per-sample bookkeeping: moments added every sample, checkpoints in their own list."""

    __slots__ = ("_cps", "_since_cp", "_wn")

    def _restart(self, w: complex, t: int) -> None:
        super()._restart(w, t)
        self._sums.add(0j)
        self._nfold = 1
        self._wn = 1
        self._cps = [0j]
        self._since_cp = 0

    def sample(self, t: int, w: complex, back: complex, omega_hat: float, dt: float) -> None:
        last = self.last_t
        self.last_t = t
        if last < 0 or t - last > self._max_gap:
            self._restart(w, t)
        else:
            gap = t - last - 1
            s = self._s
            wp = self._w_prev
            if gap > 0:
                if self.ready:
                    wp = 1j * omega_hat * self.z * back
                s += gap * dt * wp
            s += 0.5 * dt * (wp + w)
            self._s = s
            self._w_prev = w
            self._sums.add(s)
            self._pts.append(s)
            self._nfold = len(self._pts)
            self._wn += 1
            self._rot += abs(omega_hat) * dt * (gap + 1)
            self._since_cp += 1
            if self._since_cp >= self._check:
                self._since_cp = 0
                self._cps.append(s)
                assert self._cps == self._pts[:: self._check]
                if self._wn >= self._min_ticks and (
                    omega_hat == 0.0 or self._rot >= 0.8 * self._arc or t - self._t0 >= self._max_ticks
                ):
                    self._try_fit(back, t)
        if not self.ready:
            return
        r = self.r
        sig2 = omega_hat * omega_hat * r * r
        if sig2 < self._gate2 or sig2 <= 0.0:
            return
        zt = self.z * back
        cr = zt.imag * w.real - zt.real * w.imag
        ci = zt.real * w.real + zt.imag * w.imag
        if cr < 0.0:
            cr = -cr
            ci = -ci
        mag = math.sqrt(cr * cr + ci * ci)
        if mag <= 0.0:
            return
        p = self._p
        k = p / (p + self._noise2 / sig2)
        self._p = p - k * p
        z = self.z * complex(1.0, k * ci / mag)
        self.z = z * (r / abs(z))


def _make(cls):  # type: ignore[no-untyped-def]
    e = EstimatorSpec()
    pe = cls(
        dt=0.01, sigma_v=0.3, fit_arc=e.fit_arc, fit_min_ticks=e.fit_min_ticks, fit_max_ticks=e.fit_max_ticks,
        fit_check_ticks=e.fit_check_ticks, max_gap_ticks=e.max_gap_ticks, angle_walk=e.angle_walk, gate_snr=e.gate_snr,
    )
    pe._axis = True  # the reference is the axis form of the angle correction (EstimatorSpec.angle_meas)
    return pe


def test_pair_estimator_with_deferred_moments_matches_per_sample_moments() -> None:
    """Spin-up from rest, lost samples (bridged and window-restarting gaps), late samples."""
    rng = np.random.default_rng(11)
    fast, ref = _make(PairEstimator), _make(_ReferencePair)
    z = 1.2 - 0.4j
    dt = 0.01
    om_hat = 0.0
    t = 0
    while t < 6000:
        om = min(1.2, 0.002 * t)
        z *= complex(math.cos(om * dt), math.sin(om * dt))
        if rng.random() < 0.004:
            t += int(rng.integers(1, 40))  # a gap (some longer than max_gap_ticks)
            continue
        w = 1j * om * z + complex(*rng.normal(0.0, 0.3 * math.sqrt(2), 2))
        back = complex(math.cos(-om_hat * dt), math.sin(-om_hat * dt)) if t % 7 == 0 else 1.0
        fast.sample(t, w, back, om_hat, dt)
        ref.sample(t, w, back, om_hat, dt)
        if fast.ready and om_hat == 0.0:
            om_hat = fast.omega_fit
        rot = complex(math.cos(om_hat * dt), math.sin(om_hat * dt))
        fast.predict(rot)
        ref.predict(rot)
        assert (fast.z, fast.r, fast._p, fast.windows, fast.rejected, fast.omega_fit) == (
            ref.z, ref.r, ref._p, ref.windows, ref.rejected, ref.omega_fit
        ), t
        t += 1
    assert fast.windows >= 3 and fast.ready
