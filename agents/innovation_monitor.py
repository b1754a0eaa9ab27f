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
clock, socket or RNG. See docs/innovation-monitor.md.
"""

from __future__ import annotations

import math

import numpy as np

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


def cholesky2(s00: float, s01: float, s11: float) -> tuple[float, float, float] | None:
    """The lower Cholesky factor (l00, l10, l11) of the 2x2 covariance [[s00, s01], [s01, s11]]; None when
    it is not positive definite (the update is then not tested)."""
    if not (s00 > 0.0):
        return None
    l00 = math.sqrt(s00)
    l10 = s01 / l00
    d = s11 - l10 * l10
    if not (d > 0.0):
        return None
    return l00, l10, math.sqrt(d)


def whiten(chol: tuple[float, float, float], x0: float, x1: float) -> tuple[float, float]:
    """L^-1 x by forward substitution, L = cholesky2(...)."""
    l00, l10, l11 = chol
    w0 = x0 / l00
    return w0, (x1 - l10 * w0) / l11


class InnovationMonitor:
    """One agent's windows of whitened innovations and signatures (module docstring)."""

    def __init__(self, window: int, lags: int, alpha: float) -> None:
        if window <= 2 * lags:
            raise ValueError("the window must be longer than twice the whiteness test's lags")
        self.window = window
        self.lags = lags
        self.alpha = alpha
        self.level = alpha / (1 + len(SIGNATURES))
        self.w = np.zeros((window, 2))
        self.sig = np.zeros((window, len(SIGNATURES), 2))
        self.k = 0
        self.pvalues = [math.nan] * (1 + len(SIGNATURES))  # of the last complete window
        self.alarm = math.nan
        self.windows = 0
        self.alarms = 0

    def reset(self) -> None:
        """Drop the window being filled (the filter restarted: its innovations start afresh)."""
        self.k = 0

    def observe(self, e: complex, s00: float, s01: float, s11: float, vc: complex, om: float, q: complex,
                f: complex) -> None:
        """One update's innovation e with covariance [[s00, s01], [s01, s11]] and the signatures' inputs."""
        chol = cholesky2(s00, s01, s11)
        if chol is None or e != e:
            return
        k = self.k
        self.w[k] = whiten(chol, e.real, e.imag)
        a = abs(vc)
        qp = om * complex(-q.imag, q.real)  # omega q_i^perp
        sig = self.sig[k]
        for c, g in enumerate((vc, vc / a if a > 0.0 else 0j, qp, f)):
            sig[c] = whiten(chol, g.real, g.imag)
        self.k = k = k + 1
        if k == self.window:
            self.k = 0
            self.pvalues = p = window_pvalues(self.w, self.sig, self.lags)
            alarm = any(v < self.level for v in p)
            self.alarm = 1.0 if alarm else 0.0
            self.windows += 1
            self.alarms += alarm

    def entries(self) -> dict[str, float]:
        """The estimate entries (``MONITOR_NAMES``): the last complete window's p-values and alarm, counts."""
        out = dict(zip(MONITOR_NAMES, self.pvalues, strict=False))
        out["mon_alarm"] = self.alarm
        out["mon_windows"] = float(self.windows)
        out["mon_alarms"] = float(self.alarms)
        return out
