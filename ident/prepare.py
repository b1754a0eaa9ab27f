"""The recording as the fit needs it: noise floors from the data, glitches left out, velocities that are
differences of positions recognised, a long recording's windows chosen. Pure functions of the recording
(ident/recording.py) that return what the diagnosis (ident/select.py) uses, and the warnings a user reads
about them. See docs/diagnose.md, "Input" and "Method".
"""

from __future__ import annotations

import math
from dataclasses import replace
from statistics import NormalDist

import numpy as np

from ident import stats
from ident.glitches import GLITCH_FLOORS, find_glitches
from ident.recording import Recording


def noise_floor(rec: Recording) -> tuple[float, float]:
    """(sigma_v m/s, sigma_p m) estimated from the data; NaN for an absent channel."""
    sv = sp = math.nan
    if rec.vel is not None:
        sv = stats.kinematic_noise(rec.vel) if rec.n >= 3 else math.nan
        if not math.isfinite(sv):
            sv = stats.difference_noise(rec.t, rec.vel, 3)
    if rec.pos is not None:
        sp = stats.difference_noise(rec.t, rec.pos, 3)
    return sv, sp


AGENT_SPREAD = 1.5  # agents whose noise floors differ by more than this factor are weighted each by its own


def agent_floors(rec: Recording, data: np.ndarray | None) -> np.ndarray | None:
    """Per-agent noise floors (n, 1) of ``data`` (velocities or positions) when the agents' sensors differ:
    each agent's own divided-difference noise (the pooled kinematic floor mixes the agents: its rank-one
    fit takes up part of the noisiest agent's noise); None when they agree within ``AGENT_SPREAD`` (the
    pooled floor for all) or cannot be told apart."""
    if data is None or rec.n < 2:
        return None
    own = np.array([stats.difference_noise(rec.t, data[:, i], 3) for i in range(rec.n)])
    if not np.isfinite(own).all() or own.min() <= 0 or own.max() / own.min() <= AGENT_SPREAD:
        return None
    return own[:, None]


def usable_floor(x: float, data: np.ndarray | None) -> float:
    """A usable weight: a zero or NaN floor (quantised, noiseless data) becomes a tiny share of the signal."""
    if data is None:
        return math.nan
    scale = float(np.nanstd(data)) or 1.0
    return x if math.isfinite(x) and x > 1e-9 * scale else 1e-9 * scale


DIFFERENCED_LAG1 = -0.4  # white sensor noise gives ~0, velocities from differenced positions -1/2


def differenced_velocities(rec: Recording, warns: list[str]) -> float:
    """The correlation of consecutive velocity noise samples to whiten the residual with: a velocity that is
    a difference of noisy positions ((n_k - n_(k-1)) / dt, an encoder's counts over the sample period) has
    noise correlated -1/2 from one sample to the next, which no whiteness test accepts; 0 otherwise."""
    if rec.vel is None:
        return 0.0
    rho = stats.kinematic_lag1(rec.vel)
    if not rho < DIFFERENCED_LAG1:
        return 0.0
    warns.append(f"the velocities' noise is correlated {rho:.2f} from one sample to the next: they are differences "
                 "of noisy positions (an encoder's counts over the sample period), each the mean velocity over the "
                 "interval before its stamp: modelled so, and the residual whitened for the noise")
    return -0.5  # white position noise differenced: exactly; a window's covariance stays positive definite


CORRELATED_LEVEL = 1e-3  # the selection's level: white noise's remainder passes this test once in 1000 recordings
CORRELATED_MIN = 0.1  # below it the correlation widens the intervals by less than 10 % ((1 + rho) / (1 - rho))
CORRELATED_LAGS = 10  # lags over which the remainder must decay as an AR(1)'s, phi^k


def correlated_velocities(rec: Recording, warns: list[str]) -> dict | None:
    """The velocity noise's correlation in time, measured on the rigid-body kinematics' remainder (n >= 3;
    no dynamics model involved): ``{"lag1", "tau_s", "ar1", "p", "acf"}``, ``tau_s`` > 0 where the noise is
    modelled as a first-order low-pass of white noise (an AR(1) in continuous time; the residual is then
    whitened for it, :func:`ident.fit.correlated`), 0 otherwise; None without the data to measure it.

    A lab's velocity is often a filtered estimate, whose noise correlates over the filter's time constant;
    the fit's intervals, F-tests and whiteness test assume white noise. Modelled when the lag-1 correlation
    passes a one-sided test at :data:`CORRELATED_LEVEL` against white noise, is at least
    :data:`CORRELATED_MIN`, and the correlations at lags 2..:data:`CORRELATED_LAGS` are an AR(1)'s, phi^k
    (each within its Bartlett standard error at the same level, Bonferroni over the lags): a signal the
    kinematics lack (one logger's clock offset, a velocity in a robot's frame) also correlates the
    remainder, but as a slow signal does, nearly flat over these lags, and is left to the fit."""
    if rec.vel is None or rec.n < 3:
        return None
    acf, pairs = stats.kinematic_acf(rec.vel, CORRELATED_LAGS)
    if not np.isfinite(acf[0]) or pairs[0] < 50:
        return None
    dims = 2 * (rec.n - 2)  # the remainder's independent real components per stamp
    phi = float(acf[0])
    p = 1.0 - NormalDist().cdf(phi * math.sqrt(pairs[0] * dims))
    k = np.arange(2, CORRELATED_LAGS + 1)
    ok = np.isfinite(acf[1:]) & (pairs[1:] > 0)
    ar1 = False
    if p < CORRELATED_LEVEL and phi >= CORRELATED_MIN and phi < 1.0 and ok.any():
        k, r, nk = k[ok], acf[1:][ok], pairs[1:][ok]
        p2, p2k = phi * phi, phi ** (2 * k)
        bartlett = (1 + p2) * (1 - p2k) / (1 - p2) - 2 * k * p2k  # var(r_k) N of an AR(1)
        own = k * k * phi ** (2 * k - 2) * (1 - p2)  # phi^k's own, phi read from r_1
        z = np.abs(r - phi**k) / np.sqrt((bartlett + own) / (nk * dims))
        ar1 = bool(z.max() < NormalDist().inv_cdf(1.0 - CORRELATED_LEVEL / (2 * k.size)))
    dtm = float(np.median(np.diff(rec.t)))
    tau = -dtm / math.log(phi) if ar1 else 0.0
    if ar1:
        warns.append(f"the velocities' noise is correlated in time: lag-1 correlation {phi:.2f}, as a first-order "
                     f"low-pass of {1000 * tau:.3g} ms (a filtered velocity estimate; measured on the rigid-body "
                     "kinematics alone): the residual is whitened for it, and the intervals and tests account "
                     "for it")  # fmt: skip
    return {"lag1": phi, "tau_s": tau, "ar1": ar1, "p": p, "acf": acf.tolist()}


RUN = 4  # consecutive windows kept together: the rotation's links between them carry J's information


def spread_windows(S: int, keep: int) -> np.ndarray:
    """Indices of ``keep`` of ``S`` windows, in runs of :data:`RUN` consecutive ones spread evenly."""
    if keep >= S:
        return np.arange(S)
    runs = max(1, -(-keep // RUN))
    starts = np.round(np.linspace(0, S - RUN, runs)).astype(int)
    return np.unique((starts[:, None] + np.arange(RUN)).ravel())


def without_glitches(rec: Recording, warns: list[str]) -> Recording:
    """``rec`` with its glitches (ident/glitches.py, against each agent's own divided-difference floor: a
    noisier sensor's samples are not glitches) not measured, and a warning per channel that had any."""
    out = rec
    for key in ("vel", "pos"):
        data = getattr(rec, key)
        if data is None:
            continue
        sig = np.array([stats.difference_noise(rec.t, data[:, i], 3) for i in range(rec.n)])
        flags = find_glitches(rec.t, data, sig)
        if not flags.any():
            continue
        clean = data.copy()
        clean[flags] = np.nan
        out = replace(out, **{key: clean})
        k, i = np.nonzero(flags)
        warns.append(f"{int(flags.sum())} {'velocity' if key == 'vel' else 'position'} samples "
                     f"({100 * flags.sum() / np.count_nonzero(~np.isnan(data[..., 0])):.2g} %) are more than "
                     f"{GLITCH_FLOORS:g} noise floors off the cubic through their neighbours (agents "
                     f"{sorted(set(i.tolist()))}, the first at t = {rec.t0 + rec.t[k.min()]:.6g} s): left out as glitches")
    return out
