"""Per-neighbour estimation of z_ij = p_Ci - p_Cj (paper 000 Sec. IV-A, blocks 1-4 of Fig. 2).

A view: one pair estimator is a row (b, k) of a bank of agents/kernels/pair.py (its own bank of one, or an
agent's: :meth:`PairEstimator.of`), whose kernels do the maths (circle fit of the integrated relative
velocity, angle tracking). Why this shape: docs/agent-step.md ("The pair estimator"); the high-noise
spin-up: docs/spinup.md.
"""

from __future__ import annotations

import numpy as np

from agents.kernels.pair import pair_bank, pair_checkpoints, pair_predict, pair_sample, set_pair_params


class PairEstimator:
    """Agent i's estimator of z_ij for one neighbour j. O(1) per sample.

    The owner keeps ``z`` at its own state tick (predicting it by rotation every tick) and feeds
    samples w = v_Ci - v_Cj at the tick they were measured (strictly increasing ticks).
    """

    __slots__ = ("P", "cps", "prm", "b", "k", "_z", "_ready", "_r", "_p", "_windows", "_rejected", "_omega_fit")

    def __init__(
        self,
        *,
        dt: float,
        sigma_v: float,
        fit_arc: float,
        fit_min_ticks: int,
        fit_max_ticks: int,
        fit_check_ticks: int,
        max_gap_ticks: int,
        angle_walk: float,
        gate_snr: float,
        angle_meas: str = "linear",
    ) -> None:
        self.P, self.cps, self.prm = pair_bank(1, 1, pair_checkpoints(fit_min_ticks, fit_max_ticks, fit_check_ticks))
        set_pair_params(
            self.P, self.prm, 0, dt=dt, sigma_v=sigma_v, fit_arc=fit_arc, fit_min_ticks=fit_min_ticks,
            fit_max_ticks=fit_max_ticks, fit_check_ticks=fit_check_ticks, max_gap_ticks=max_gap_ticks,
            angle_walk=angle_walk, gate_snr=gate_snr, angle_meas=angle_meas,
        )  # fmt: skip
        self._view(0, 0)

    @classmethod
    def of(cls, P: np.ndarray, cps: np.ndarray, prm: np.ndarray, b: int, k: int) -> PairEstimator:
        """The pair estimator in row (b, k) of an existing bank (an agent's, agents/kernels/pair.py)."""
        pe = cls.__new__(cls)
        pe.P, pe.cps, pe.prm = P, cps, prm
        pe._view(b, k)
        return pe

    def _view(self, b: int, k: int) -> None:
        # the fields' one-element views, read with .item(0): Python scalars, as the owner's messages need
        self.b, self.k = b, k
        row = self.P[b, k:k + 1]
        self._z, self._ready, self._r, self._p = row["z"], row["ready"], row["r"], row["p"]
        self._windows, self._rejected, self._omega_fit = row["windows"], row["rejected"], row["omega_fit"]

    @property
    def z(self) -> complex:
        """Estimate of z_ij (m, world) at the owner's state tick; 0 until the first fit."""
        return self._z.item(0)

    @property
    def ready(self) -> bool:
        """A window has been accepted: ``z`` and ``r`` are estimates."""
        return self._ready.item(0)

    @property
    def r(self) -> float:
        """|z_ij| estimate (m)."""
        return self._r.item(0)

    @property
    def p(self) -> float:
        """Angle error variance of ``z`` (rad^2)."""
        return self._p.item(0)

    @property
    def windows(self) -> int:
        """Accepted circle-fit windows."""
        return self._windows.item(0)

    @property
    def rejected(self) -> int:
        """Windows closed without an accepted fit."""
        return self._rejected.item(0)

    @property
    def omega_fit(self) -> float:
        """omega over the last third of the last accepted window (rad/s)."""
        return self._omega_fit.item(0)

    def predict(self, rot: complex) -> None:
        """Advance one tick: rotate by e^{i omega_hat dt}; the angle uncertainty grows."""
        pair_predict(self.P, self.b, self.k, rot)

    def sample(self, t: int, w: complex, back: complex, omega_hat: float, dt: float) -> None:
        """Use the relative velocity ``w`` measured at tick ``t``; ``back`` rotates the state-tick estimate
        back to tick t (1 when t is the state tick)."""
        pair_sample(self.P, self.cps, self.prm, self.b, self.k, t, w, complex(back), omega_hat, dt)
