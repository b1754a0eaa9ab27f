"""The recording as the fit needs it: noise floors from the data, glitches left out, velocities that are
differences of positions recognised, a long recording's windows chosen. Pure functions of the recording
(ident/recording.py) that return what the diagnosis (ident/select.py) uses, and the warnings a user reads
about them. See docs/diagnose.md, "Input" and "Method".
"""

from __future__ import annotations

import math
from dataclasses import replace

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
