"""The timing effects in words, and which shape of a force lag (late rows, a first-order low-pass) fits.

:func:`force_lag_shape` refits a named force lag in its other shape; :func:`lag_text` and :func:`at_bound`
are the lines a person reads for a named timing effect and for a non-negative candidate held at its bound.
"""

from __future__ import annotations

from collections.abc import Callable

from ident import stats
from ident.fit import Fit, Problem, lm_fit
from ident.model import expand


def lag_text(name: str, d: float, h: float, shape: tuple[str, float, bool] | None = None) -> str:
    """A named timing effect in words: which sensor lags, by how much, and what the data tell of its shape
    (``shape``: :func:`force_lag_shape`'s comparison with the other shape of a force lag)."""
    val = f"{1e3 * d:.3g} +- {1e3 * h:.2g} ms"
    if name == "measurement_delay":
        return (f"measurement_delay: the velocities are measured {val} after the forces that moved the load: their "
                "rows are stamped that late, or the velocity sensors low-pass with a time constant of about that "
                "(below their bandwidth the two look alike)")
    head = (f"force_sensor_lag: the logged forces lag the ones that moved the load by {val}: the force rows are "
            "stamped that late, or the force sensors filter with about that delay (a filter of higher order than "
            "the first: its group delay)" if name == "force_sensor_lag" else
            f"force_sensor_lowpass: the force sensors low-pass the force that moved the load with a time constant "
            f"of {val} (first order): the logged forces lag it by about that")
    if shape is None:
        return head + " (below the sensors' bandwidth a late stamp and a low-pass look alike)"
    other, dbic, apart = shape
    alt = "a first-order low-pass" if other == "force_sensor_lowpass" else "a late stamp"
    if apart:
        return head + f"; {alt} fits worse (BIC higher by {dbic:.3g})"
    return head + f"; these data do not tell it from {alt} (its BIC higher by only {dbic:.2g}: it does not add to it)"


BOUND_HINT = {
    "measurement_delay": "the motion leads the logged force, as it does behind force sensors that lag "
                         "(force_sensor_lag, force_sensor_lowpass)",
    "force_sensor_lag": "the logged force leads the motion, as it does with velocities measured late "
                        "(measurement_delay)",
    "force_sensor_lowpass": "the logged force leads the motion, as it does with velocities measured late "
                            "(measurement_delay)",
}


def at_bound(name: str, p: float) -> str:
    """The line for a non-negative candidate held at 0 by a fit that wants it negative."""
    hint = BOUND_HINT.get(name, "a negative value no physical effect of its kind has: the residual holds something "
                                "else, outside the vocabulary")
    return f"{name}: held at its bound 0, and the data want it below (score test p {p:.2g}): {hint}"


FORCE_LAG = ("force_sensor_lag", "force_sensor_lowpass")


def force_lag_shape(pb: Problem, fit: Fit, accepted: list[str], alpha: float,
                     say: Callable[[str], None]) -> tuple[Fit, tuple[str, float, bool] | None]:
    """A force lag named in one shape (late rows, a first-order low-pass) refitted in the other, beside the
    same effects: the one that fits better is kept (``accepted`` updated). Returns the fit and (the other shape,
    its BIC above the kept one's, told apart: the kept shape adds to the other at level ``alpha``), or None
    when no single force lag is named."""
    named = [c for c in FORCE_LAG if c in accepted]
    if len(named) != 1:
        return fit, None
    c = named[0]
    other = FORCE_LAG[1 - FORCE_LAG.index(c)]
    say(f"{c}: refitted as {other}")
    lay2 = fit.lay.with_effects(tuple(other if e == c else e for e in fit.lay.effects))
    g2 = expand(lay2, fit.g, fit.lay, {other: float(fit.g[fit.lay.slot(c)][0])})
    alt = lm_fit(pb, lay2, g2, fit.x)
    if alt.rss < fit.rss:  # the same number of parameters: the lower residual is the lower BIC
        accepted[accepted.index(c)] = other
        fit, alt, c, other = alt, fit, other, c
    lay3 = fit.lay.with_effects(fit.lay.effects + (other,))
    joint = lm_fit(pb, lay3, expand(lay3, fit.g, fit.lay), fit.x)
    adds = stats.nested_f(alt.rss, joint.rss, 1, joint.N, joint.P)[1] < alpha  # the kept shape beside the other
    return fit, (other, alt.bic - fit.bic, adds)
