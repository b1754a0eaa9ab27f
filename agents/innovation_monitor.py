"""Innovation monitor: does the agent's own filter leave structure in its velocity innovations?

:class:`InnovationMonitor` is fed once per filter update with the own-velocity innovation e (2-vector,
world frame), its covariance S (2x2, from the filter) and the candidate signatures the agent forms
locally before the update: the filter's v_C, the unit vector of v_C (sign(v_C): Coulomb friction),
omega q_i^perp (an omega error's velocity at the contact: rotational damping) and the own applied
force f_i. Over consecutive windows of ``window`` updates it tests, on the whitened innovations
w = L^-1 e (S = L L^T; signatures whitened alike):

- whiteness against persistence: z = sqrt(N) sum_c sum_{k=1..h} r_{c,k} / sqrt(2h), r_{c,k} the lag-k
  autocorrelation of component c normalised by the window's own sum of squares (a filter whose S is off
  by a constant factor is the lock check's business, not this test's); N(0, 1) under H0, one-sided
  (large z). One-sided because the filter's process noise leaves clean innovations slightly negatively
  correlated (r_k about -0.03 at lags 1-12), which a two-sided Ljung-Box Q takes for structure in a
  quarter of clean windows (docs/innovation-monitor.md), while a missing effect leaves a slowly varying
  residual: positive correlation;
- correlation with each signature g: the score statistic T = (sum w.g)^2 / (sigma^2 sum |g|^2), sigma^2
  = sum |w|^2 / 2N (chi-square with 1 degree of freedom under H0: g is known before w).

A window raises an alarm when any of the five p-values is below alpha / 5 (Bonferroni): its false-alarm
rate is at most ``alpha`` when the filter's model is right. Report-only: nothing is switched. Pure: no
clock, socket or RNG. See docs/innovation-monitor.md. The window's fill runs compiled
(agents/kernels/window_stats.py); its p-values, once per window, are computed here with numpy.
"""

from __future__ import annotations

import math

import numpy as np

import agents.kernels.window_stats as ws

SIGNATURES = ("vc", "sgn", "om", "f")
MONITOR_NAMES = ("mon_p_white", "mon_p_vc", "mon_p_sgn", "mon_p_om", "mon_p_f", "mon_alarm", "mon_windows",
                 "mon_alarms")


def chi2_sf_1(x: float) -> float:
    """P(X > x) for a chi-square variable with one degree of freedom."""
    return math.erfc(math.sqrt(0.5 * x)) if x > 0.0 else 1.0


def persistence_p(w: np.ndarray, lags: int) -> float:
    """One-sided p-value of positive autocorrelation at lags 1..``lags`` in the whitened innovations ``w``
    (N x 2): z = sqrt(N) sum of the autocorrelations / sqrt(columns x lags), N(0, 1) for white w."""
    n = len(w)
    acc = 0.0
    m = 0
    for c in range(w.shape[1]):
        x = w[:, c]
        den = float(x @ x)
        if den <= 0.0:
            continue
        for k in range(1, lags + 1):
            acc += float(x[k:] @ x[:-k]) / den
            m += 1
    if not m:
        return math.nan
    z = math.sqrt(n) * acc / math.sqrt(m)
    return 0.5 * math.erfc(z / math.sqrt(2.0))


def score_test(w: np.ndarray, g: np.ndarray) -> float:
    """p-value of the score test of w (N x 2) against signature g (N x 2), both whitened (NaN if g is 0)."""
    gg = float(np.sum(g * g))
    ww = float(np.sum(w * w))
    if gg <= 0.0 or ww <= 0.0:
        return math.nan
    s = float(np.sum(w * g))
    sigma2 = ww / w.size
    return chi2_sf_1(s * s / (sigma2 * gg))


def window_pvalues(w: np.ndarray, sig: np.ndarray, lags: int) -> list[float]:
    """The five p-values of one window: whiteness, then each signature of ``sig`` (N x 4 x 2)."""
    return [persistence_p(w, lags)] + [score_test(w, sig[:, k, :]) for k in range(sig.shape[1])]


class InnovationMonitor:
    """One agent's windows of whitened innovations and signatures (module docstring): a view over row ``b`` of
    the monitor arrays (agents/kernels/window_stats.py); its own by default."""

    def __init__(self, window: int, lags: int, alpha: float, rows: tuple | None = None, b: int = 0) -> None:
        """``rows``: the (mon_k, mon_f, mon_ws) arrays of :func:`monitor_rows` to view row ``b`` of (default: one
        row of its own)."""
        if window <= 2 * lags:
            raise ValueError("the window must be longer than twice the whiteness test's lags")
        self.window = window
        self.lags = lags
        self._k, self._f, self._ws = ws.monitor_rows(1, window, alpha) if rows is None else rows
        self.b = b
        self._entries = self._f[b, :ws.ME_LEVEL]

    @property
    def k(self) -> int:
        """Updates in the window being filled."""
        return int(self._k[self.b])

    @property
    def w(self) -> np.ndarray:
        """The whitened innovations of the window (window x 2)."""
        return self._ws[self.b, :, 0]

    @property
    def sig(self) -> np.ndarray:
        """The whitened signatures of the window (window x 4 x 2)."""
        return self._ws[self.b, :, 1:]

    def reset(self) -> None:
        """Drop the window being filled (the filter restarted: its innovations start afresh)."""
        self._k[self.b] = 0

    def observe(self, e: complex, s00: float, s01: float, s11: float, vc: complex, om: float, q: complex,
                f: complex) -> None:
        """One update's innovation e with covariance [[s00, s01], [s01, s11]] and the signatures' inputs."""
        if ws.monitor_observe(self.b, self._k, self._ws, e, s00, s01, s11, vc, om, q, f):
            self.judge()

    def judge(self) -> None:
        """The complete window's p-values and alarm (once :func:`ws.monitor_observe` has filled it)."""
        # the innovations contiguous, as the p-values' dot products have always seen them
        p = window_pvalues(np.ascontiguousarray(self.w), self.sig, self.lags)
        ws.monitor_judge(self.b, self._f, np.array(p))

    def entries(self) -> dict[str, float]:
        """The estimate entries (``MONITOR_NAMES``): the last complete window's p-values and alarm, counts."""
        return dict(zip(MONITOR_NAMES, self._entries.tolist(), strict=True))
