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
from ident.fit import NoiseAR, whiten_ar
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
CORRELATED_LAGS = 10  # lags of the remainder's autocorrelation reported (JSON)
NOISE_ORDER = 30  # the longest autoregression of the noise (a digital Butterworth's spectral zero at the Nyquist
# frequency wants ever more: 30 leaves its remainder white at the whiteness test's 0.1 s blocks, p 0.13-0.99)
REGULAR = 0.1  # intervals within this share of the median are one sample period (a logger rounding its stamps)


def remainder_whiteness(r: np.ndarray, t: np.ndarray, noise: NoiseAR, block_s: float, lags: int) -> float:
    """Ljung-Box p of the rigid-body kinematics' remainder (:func:`ident.stats.kinematic_columns`' ``r`` at the
    stamps ``t``) whitened for ``noise`` (the fit's whitening, :func:`ident.fit.whiten_ar`), on its 2(n - 2)
    independent components, ``block_s`` block means and ``lags`` lags as the fit's whiteness test: whether
    the noise model leaves the sensors' noise white."""
    x = whiten_ar(r[None, :, :, None], t[None], np.ones((1,) + r.shape), noise)[0, :, :, 0]
    dims = r.shape[1] - 4  # 2(n - 2): r holds each agent's x and y
    x = x @ np.linalg.svd(x, full_matrices=False)[2][:dims].T  # the remainder's own subspace
    block = max(1, round(block_s / noise.dt))
    return stats.ljung_box(stats.block_average(x, block), lags)[2]


def correlated_velocities(rec: Recording, warns: list[str], block_s: float, lags: int) -> dict | None:
    """The velocity noise's correlation in time, measured on the rigid-body kinematics' remainder (n >= 3;
    no dynamics model involved), as an autoregression of order ``order`` (0: treated as white) whose
    predictors the fit whitens the residual with (:func:`ident.fit.correlated`); None without the data to
    measure it. ``{"lag1", "p", "acf", "modelled", "order", "partial", "coefficients", "tau_s", "ar1",
    "partial2_z", "whitened_p"}``.

    A lab's velocity is often a filtered estimate, whose noise correlates over the filter's time; the fit's
    intervals, F-tests and whiteness test assume white noise. Modelled when the lag-1 correlation passes a
    one-sided test at :data:`CORRELATED_LEVEL` against white noise, is at least :data:`CORRELATED_MIN`, and
    the correlation is that of a low-pass of white noise, rounded at lag 0: its lag-2 partial correlation
    (kappa_2, 0 for a first-order low-pass, negative for higher orders and moving averages) not above 0
    at the same level. A signal the kinematics lack (one logger's clock offset, a velocity in a robot's
    frame, one agent noisier than the rigid-body fit allows) adds a slow remainder to the white sensor
    noise: its correlation drops at lag 1 and stays (a positive kappa_2), and it is left to the fit. The
    order is the BIC's among 1..:data:`NOISE_ORDER` (Burg's reflection coefficients, pooled over the
    remainder's columns); on irregular stamps, where a lag of k samples is no fixed time, it is 1 (a
    first-order low-pass in continuous time). ``tau_s``: the first-order low-pass's time constant, or for
    a higher order the integral correlation time, dt / 2 x the model's spectrum at 0 over its variance; 0 when not
    modelled.
    The model must leave the remainder white (:func:`remainder_whiteness` at the same level, ``block_s``
    and ``lags`` the fit's whiteness test's): a moving average (a boxcar) has zeros in its spectrum that no
    finite autoregression inverts, and is then treated as white, with a warning."""
    got = None if rec.vel is None else stats.kinematic_columns(rec.vel)
    if got is None:
        return None
    r, idx = got  # the remainder once: its correlation, its autoregression and the whitened check read it
    acf, pairs = stats.kinematic_acf(r, idx, CORRELATED_LAGS)
    if not np.isfinite(acf[0]) or pairs[0] < 50:
        return None
    dims = 2 * (rec.n - 2)  # the remainder's independent real components per stamp
    N = pairs[0] * dims
    phi = float(acf[0])
    p = 1.0 - NormalDist().cdf(phi * math.sqrt(N))
    dts = np.diff(rec.t)
    dtm = float(np.median(dts))
    regular = bool(np.mean(np.abs(dts - dtm) <= REGULAR * dtm) > 0.99)
    out = {"lag1": phi, "p": p, "acf": acf.tolist(), "modelled": False, "order": 0, "partial": [],
           "coefficients": [], "tau_s": 0.0, "ar1": False, "partial2_z": math.nan, "whitened_p": math.nan}  # fmt: skip
    if not (p < CORRELATED_LEVEL and CORRELATED_MIN <= phi < 1.0):
        return out
    kappa = stats.burg(stats.kinematic_segments(r, idx), NOISE_ORDER if regular else 2)
    z2 = float(kappa[1] * math.sqrt(N))  # kappa_2's standard error is 1/sqrt(N) for an AR(1)
    out["partial2_z"] = z2
    if z2 > NormalDist().inv_cdf(1.0 - CORRELATED_LEVEL):
        return out
    A, var = stats.ar_table(kappa)  # every order's predictors and innovation variance: the BIC picks one
    order = int(np.argmin(N * np.log(var[1:]) + np.arange(1, kappa.size + 1) * math.log(N))) + 1 if regular else 1
    A = A[: order + 1, :order]
    factor = float(var[order] / (1.0 - A[order].sum()) ** 2)  # slow signals: this many samples per independent one
    tau = -dtm / math.log(kappa[0]) if order == 1 else 0.5 * dtm * factor
    noise = NoiseAR(tuple(kappa[:order].tolist()), dtm, tau if order == 1 else 0.0)
    p_white = remainder_whiteness(r, rec.t[idx], noise, block_s, lags)
    out["whitened_p"] = p_white
    if p_white < CORRELATED_LEVEL:
        warns.append(f"the velocities' noise is correlated in time (lag-1 correlation {phi:.3g}, measured on the "
                     f"rigid-body kinematics alone), but no autoregression of order up to {NOISE_ORDER} whitens it "
                     f"(Ljung-Box p {p_white:.2g} of the whitened remainder; a moving average's spectral zeros "
                     "would need an endless one): treated as white noise, so the intervals are too narrow and the "
                     "tests see the correlation as structure")  # fmt: skip
        return out
    out.update(modelled=True, order=order, partial=kappa[:order].tolist(), coefficients=A[order].tolist(),
               tau_s=tau, ar1=order == 1)  # fmt: skip
    shape = (f"as a first-order low-pass of {1000 * tau:.3g} ms" if order == 1 else
             f"as an autoregression of order {order} (a filter of higher order than a first-order low-pass; "
             f"correlation time {1000 * tau:.3g} ms)")  # fmt: skip
    warns.append(f"the velocities' noise is correlated in time: lag-1 correlation {phi:.3g}, {shape}, measured on "
                 f"the rigid-body kinematics alone (a filtered velocity estimate): slow signals carry {factor:.3g}x "
                 "less information than white noise of its level would; the residual is whitened for it, and the "
                 "intervals and tests account for it")  # fmt: skip
    return out


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
