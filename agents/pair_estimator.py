"""Per-neighbour estimation of z_ij = p_Ci - p_Cj (paper 000 Sec. IV-A, blocks 1-4 of Fig. 2).

|z_ij| from a circle fit of the integrated relative velocity in re-anchored windows, the direction
tracked by rotation with omega_hat and corrected by Result 1 in linear form. Pure, O(1) per sample.
Why this shape: docs/agent-step.md ("The pair estimator"); the high-noise spin-up: docs/spinup.md.
"""

from __future__ import annotations

import math
from math import atan2, sqrt

from agents.geometry import CircleFit, CircleSums


class PairEstimator:
    """Agent i's estimator of z_ij for one neighbour j. Pure, O(1) per sample.

    The owner keeps ``z`` at its own state tick (predicting it by rotation every tick) and feeds
    samples w = v_Ci - v_Cj at the tick they were measured (strictly increasing ticks).
    """

    __slots__ = (
        "z", "ready", "r", "_rw", "_rsum", "_p",
        "last_t", "_s", "_w_prev", "_sums", "_pts", "_nfold", "_rot", "_t0",
        "_arc", "_dt", "_min_ticks", "_max_ticks", "_check", "_max_gap", "_q", "_noise2", "_gate2",
        "windows", "rejected", "omega_fit", "_axis",
    )

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
        self.z = 0j  # estimate of z_ij (m, world) at the owner's state tick; 0 until the first fit
        self.ready = False
        self.r = 0.0  # |z_ij| estimate (m)
        self._rw = 0.0  # sum of window weights
        self._rsum = 0.0  # sum of weight * window radius
        self._p = 0.0  # angle error variance (rad^2)
        self.last_t = -1  # tick of the last sample used
        self._s = 0j  # window integral of the relative velocity (m)
        self._w_prev = 0j
        self._sums = CircleSums()  # moments of _pts[:_nfold]
        # the window's points s, from its anchor on: the moments are only needed when a fit is
        # tried (late in a window), so they are folded in then (same additions, same order) rather
        # than accumulated per sample; every fit_check_ticks-th point is a checkpoint for the arc
        self._pts: list[complex] = []
        self._nfold = 0
        self._rot = 0.0  # |omega_hat| integrated over the window (rad)
        self._t0 = 0  # first tick of the window
        self._arc = fit_arc
        self._dt = dt
        self._min_ticks = fit_min_ticks
        self._max_ticks = fit_max_ticks
        self._check = fit_check_ticks
        self._max_gap = max_gap_ticks
        self._q = angle_walk * angle_walk * dt
        self._noise2 = 2.0 * sigma_v * sigma_v  # variance of each component of v_Ci - v_Cj
        self._gate2 = gate_snr * gate_snr * self._noise2
        if angle_meas not in ("linear", "axis"):
            raise ValueError(f"angle_meas must be 'linear' or 'axis', got {angle_meas!r}")
        self._axis = angle_meas == "axis"
        self.windows = 0  # accepted circle-fit windows
        self.rejected = 0  # windows closed without an accepted fit
        self.omega_fit = 0.0  # mean omega over the last accepted window (arc / duration), rad/s

    # ------------------------------------------------------------------------------------ prediction
    def predict(self, rot: complex) -> None:
        """Advance one tick: rotate by e^{i omega_hat dt}; the angle uncertainty grows."""
        if self.ready:
            self.z *= rot
            self._p += self._q

    # -------------------------------------------------------------------------------------- samples
    def sample(self, t: int, w: complex, back: complex, omega_hat: float, dt: float) -> None:
        """Use the relative velocity ``w`` measured at tick ``t``.

        ``back`` rotates the state-tick estimate back to tick t (1 when t is the state tick).
        Hot path: the moment sums and the angle correction are inlined.
        """
        last = self.last_t
        self.last_t = t
        if last < 0 or t - last > self._max_gap:
            self._restart(w, t)
        else:
            gap = t - last - 1
            s = self._s
            wp = self._w_prev
            if gap > 0:
                # lost samples: bridge the integral with the model's relative velocity i*omega*z
                if self.ready:
                    wp = 1j * omega_hat * self.z * back
                s += gap * dt * wp
                self._rot += abs(omega_hat) * dt * (gap + 1)
            else:
                self._rot += abs(omega_hat) * dt  # (gap + 1) == 1: the product is exact without it
            s += 0.5 * dt * (wp + w)
            self._s = s
            self._w_prev = w
            pts = self._pts
            pts.append(s)
            wn = len(pts)  # samples in the window
            # at a checkpoint (every fit_check_ticks samples), solve the fit only when the window may
            # have covered the arc (omega_hat says so), or at every checkpoint while omega_hat is not
            # known yet (bootstrap)
            if (
                not (wn - 1) % self._check
                and wn >= self._min_ticks
                and (omega_hat == 0.0 or self._rot >= 0.8 * self._arc or t - self._t0 >= self._max_ticks)
            ):
                self._try_fit(back, t)
        if not self.ready:
            return
        if self._axis:
            # the original form (EstimatorSpec.angle_meas = "axis"): the normalised axis perp(w), sign
            # nearest the prediction, gated at |omega_hat| |z_ij| >= gate_snr sigma sqrt(2)
            r = self.r
            sig2 = omega_hat * omega_hat * r * r  # (|omega| |z|)^2
            if sig2 < self._gate2 or sig2 <= 0.0:
                return
            z = self.z
            zt = z * back
            wr = w.real
            wi = w.imag
            ztr = zt.real
            zti = zt.imag
            cr = zti * wr - ztr * wi
            ci = ztr * wr + zti * wi
            if cr < 0.0:
                cr = -cr
                ci = -ci
            mag = sqrt(cr * cr + ci * ci)
            if mag <= 0.0:
                return
            p = self._p
            k = p / (p + self._noise2 / sig2)
            self._p = p - k * p
            z = z * complex(1.0, k * ci / mag)
            self.z = z * (r / abs(z))
            return
        # Result 1, linear form: w / z_ij = i omega e^{i delta} for an angle error delta of the
        # prediction, so the radial part -Re(w / zt) = omega sin(delta) (+ noise of variance
        # 2 sigma^2 / |z|^2, zero-mean) measures the angle error without normalising w or picking
        # a sign: no gate, the weight goes to 0 with omega_hat
        if omega_hat == 0.0:
            return
        z = self.z
        zt = z * back
        ztr = zt.real
        zti = zt.imag
        zz = ztr * ztr + zti * zti
        if zz <= 0.0:
            return
        meas = -(w.real * ztr + w.imag * zti) / zz  # omega sin(delta)
        p = self._p
        h = omega_hat
        k = p * h / (h * h * p + self._noise2 / zz)
        self._p = p - k * h * p
        z = z * complex(1.0, k * meas)
        self.z = z * (self.r / abs(z))

    def _restart(self, w: complex, t: int) -> None:
        """Re-anchor the window at the current sample (s := 0) so the integrated noise restarts."""
        self._s = 0j
        self._w_prev = w
        self._sums.reset()
        self._pts = [0j]
        self._nfold = 0
        self._rot = 0.0
        self._t0 = t

    def _try_fit(self, back: complex, t: int) -> None:
        pts = self._pts
        sums = self._sums
        sums.extend(pts, self._nfold)
        self._nfold = len(pts)
        fit = sums.fit()
        if fit is not None:
            radius = fit.radius
            rms = fit.rms
            span = (t - self._t0) * self._dt  # elapsed time, not samples: some may be missing
            # accept only a real arc: large enough, radius well above the integrated noise of the
            # window and mean tangential speed above the per-sample noise (rejects noise curls).
            # The two radius gates go first: they are O(1), the arc costs an atan2 per checkpoint.
            if radius > 4.0 * rms and radius * radius > 16.0 * self._noise2 * self._dt * span:
                c = fit.centre
                cx = c.real
                cy = c.imag
                cps = pts[:: self._check]  # checkpoints: every fit_check_ticks-th sample
                nseg = len(cps) - 1
                recent_from = nseg - max(1, nseg // 3)
                # sum of the angles between consecutive checkpoints seen from the centre (floats,
                # not complex temporaries; the same operations as (cps[k] - c) products); segments
                # k > recent_from also add to arc_recent
                arc = 0.0
                p0 = cps[0]
                px = p0.real - cx
                py = p0.imag - cy
                for cur in cps[1 : recent_from + 1]:
                    qx = cur.real - cx
                    qy = cur.imag - cy
                    arc += atan2(px * qy - py * qx, px * qx + py * qy)
                    px = qx
                    py = qy
                arc_recent = 0.0
                for cur in cps[recent_from + 1 :]:
                    qx = cur.real - cx
                    qy = cur.imag - cy
                    da = atan2(px * qy - py * qx, px * qx + py * qy)
                    arc += da
                    arc_recent += da
                    px = qx
                    py = qy
                if abs(arc) >= self._arc and (radius * abs(arc) / span) ** 2 >= self._noise2:
                    self._accept(fit, arc_recent, nseg, recent_from, back, t)
                    return
        if t - self._t0 >= self._max_ticks:
            self.rejected += 1
            self._restart(self._w_prev, t)

    def _accept(self, fit: CircleFit, arc_recent: float, nseg: int, recent_from: int, back: complex, t: int) -> None:
        """An accepted window: update |z_ij|, omega_fit and the angle of z_ij, then re-anchor."""
        weight = 1.0 / (fit.rms * fit.rms + 1e-12)
        self._rw += weight
        self._rsum += weight * fit.radius
        self.r = r = self._rsum / self._rw
        self.windows += 1
        # rate over the last third of the window: a spin-up is accelerating, and the
        # window mean would seed omega_hat well below the current rate
        self.omega_fit = arc_recent / ((nseg - recent_from) * self._check * self._dt) * (len(self._pts) / max(1, t - self._t0))
        c = fit.centre
        z_t = self._s - c  # z_ij at the sample tick, sign included (integral form)
        r_fit = 2.0 * (fit.rms / fit.radius) ** 2 + 1e-6  # angle variance of z_t (rad^2)
        m = abs(z_t)
        if m > 0.0:
            zt = self.z * back
            if self.ready:
                # the window's own position is an angle measurement too; a large
                # disagreement means the tracker lost lock: re-anchor on the fit
                cr = zt.real * z_t.real + zt.imag * z_t.imag
                ci = zt.real * z_t.imag - zt.imag * z_t.real
                if cr > 0.0 and abs(ci) < 0.5 * math.hypot(cr, ci):
                    p = self._p
                    k = p / (p + r_fit)
                    self._p = p - k * p
                    zt *= complex(1.0, k * ci / math.hypot(cr, ci))
                    self.z = zt / back * (r / abs(zt))
                else:
                    self.z = z_t / back * (r / m)
                    self._p = r_fit + 1e-3
            else:
                self.z = z_t / back * (r / m)
                self._p = r_fit + 1e-3
                self.ready = True
        self._restart(self._w_prev, t)
