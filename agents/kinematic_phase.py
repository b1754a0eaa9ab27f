"""The kinematic phase of one agent (paper 000 Sec. IV, blocks 1-6 of Fig. 2): z_ij, omega, z_i, control.

:meth:`KinematicPhase.step` (tick, own velocity, inbox, the dynamical phase's feedback) ->
:class:`agents.tick_records.KinematicTick`. Pure: no clock, socket or RNG. Per tick k (states refer to
tick k-1 on entry and are predicted to tick k on exit):

1. inbox, in (tick, sender) order: unknown senders, duplicates, messages from the future and
   malformed ones are dropped (counted). A message of tick t pairs the sender's velocity at t with the
   own one of the same tick (ring buffer), so the pair estimator's inputs are exact, only late; on a
   link seen to reorder, samples are held until the earlier ones arrive or are ``hold`` ticks overdue.
2. z_ij: :class:`agents.pair_estimator.PairEstimator`.
3. omega: eq. (9) pooled over the pairs as a least-squares ratio, then a low-pass consensus filter
   (:func:`agents.consensus.lowpass_step`); delayed omega information is brought forward (``_forward``).
4. z_i (Result 3) in flow form (:func:`agents.consensus.flow_step`) in a body frame phi kept in
   agreement by phase consensus (:func:`agents.consensus.average_step`).
5. control: :class:`agents.control.KinematicControl`.

Why each choice, with the wire content: docs/agent-step.md.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from math import cos, sin
from operator import attrgetter

from agents.consensus import average_step, disagreement, flow_step, lowpass_step
from agents.control import KinematicControl
from agents.pair_estimator import PairEstimator
from agents.tick_records import DynamicFeedback, DynamicMsg, KinematicTick
from config.agent_params import ControlSpec, EstimatorSpec
from net.messages import StateMsg

_HOLD_MAX = 16  # longest wait for a reordered velocity sample (ticks); well inside history_ticks
_NAN = float("nan")
_by_tick = attrgetter("tick", "sender")

# the dynamical phase's decoder of a message's states (DynamicPhase.decode): raises if malformed
Decode = Callable[[int, int, int, dict, Sequence[float] | None], DynamicMsg]


class _Nbr:
    """What the agent remembers of one neighbour."""

    __slots__ = ("id", "pair", "last", "om", "om_ok", "ph", "y", "zji", "fji", "flow", "st_t", "z_sent", "rel", "pend", "hold")

    def __init__(self, j: int, pair: PairEstimator) -> None:
        self.id = j
        self.pair = pair
        self.last = -1  # newest tick used from j
        self.om = 0.0  # j's omega consensus state
        self.om_ok = False  # j's omega (and phase) state is initialised
        self.ph = 0.0  # j's body-frame angle phi_j (rad)
        self.y = 0j  # j's centroid state in its body frame
        self.zji = 0j  # j's estimate of z_ji
        self.fji = 0j  # j's flow to us (centroid iteration in flow form)
        self.flow = 0j  # our flow to j: F_ij, kept ~ -F_ji
        self.st_t = -(10**9)  # tick of j's states (om, ph, y, zji, fji); none yet
        self.z_sent = 0j  # our z_ij as sent in our last message
        self.rel = -1  # newest tick whose velocity went to the pair estimator (or was given up on)
        self.pend: dict[int, complex] = {}  # j's velocities held back until the earlier ones arrive
        self.hold = 0  # deepest reordering seen on the link (ticks): how long a gap is waited for


class _Pool:
    """This tick's pooled eq. (9) sums: u = num / den, and what brings late samples to the state tick."""

    __slots__ = ("num", "den", "fw", "late")

    def __init__(self) -> None:
        self.num = 0.0
        self.den = 0.0
        self.fw = 0.0  # sum of |z|^2-weighted corrections that bring late samples' omega to the state tick
        self.late: list[tuple[int, float]] = []  # (tick, |z|^2) of the late samples, for the dynamical phase


class KinematicPhase:
    """Agent i's kinematic-phase estimator and controller (module docstring)."""

    def __init__(
        self,
        agent_id: int,
        neighbours: Sequence[int],
        dt: float,
        sigma_v: float,
        estimator: EstimatorSpec,
        control: ControlSpec,
        dynamic: bool,
    ) -> None:
        """``dynamic``: a dynamical phase runs on top (its feedback and feed-forward are used)."""
        self.id = agent_id
        self.dt = dt
        self.dynamic = dynamic
        self._ctl = ctl = KinematicControl(control, dt)
        # the target while the team waits for a late pair (ControlSpec.omega_boost; dynamical phase only)
        self._boost_tick = round(control.boost_after_s / dt) if control.omega_boost > 0 else -1
        self._boost_target = (1.0 if ctl.spin >= 0.0 else -1.0) * max(control.omega_boost, control.omega_target)
        self.nbrs: dict[int, _Nbr] = {}
        for j in sorted(set(int(j) for j in neighbours)):
            pe = PairEstimator(
                dt=dt,
                sigma_v=sigma_v,
                fit_arc=estimator.fit_arc,
                fit_min_ticks=estimator.fit_min_ticks,
                fit_max_ticks=estimator.fit_max_ticks,
                fit_check_ticks=estimator.fit_check_ticks,
                max_gap_ticks=estimator.max_gap_ticks,
                angle_walk=estimator.angle_walk,
                gate_snr=estimator.gate_snr,
                angle_meas=estimator.angle_meas,
            )
            self.nbrs[j] = _Nbr(j, pe)
        self._nlist = list(self.nbrs.values())
        hist = estimator.history_ticks
        self._hist = hist
        self.vbuf = [0j] * hist  # own velocities of the last ticks, to pair with late neighbour samples
        self._vtick = [-1] * hist
        self._max_age = estimator.max_age_ticks
        self._beta = min(1.0, dt / estimator.omega_tau)
        self._eps_om = estimator.omega_eps
        self._eps_z = estimator.centroid_eps
        self._eps_ph = estimator.centroid_eps
        self.omega = 0.0  # omega_hat
        self.om_init = False  # omega_hat seeded from a circle fit (or from a neighbour's value)
        self.y = 0j  # z_i in the agents' common body frame: x = e^{i phi} y
        self.phi = 0.0  # body-frame angle, integral of omega_hat kept in agreement by consensus
        self._adopt_ph = False
        self.trusted = False
        self.dropped_unknown = 0
        self.dropped_stale = 0
        self.last_tick = -1
        self._omdot = 0.0  # omega_hat's own trend per tick (its measurement path, low-passed)
        self._held = False  # some _Nbr.pend is not empty
        self._asum = 0.0  # sum of the dynamical phase's feed-forward increments alpha dt so far (rad/s)
        self._abuf = [0.0] * hist  # _asum at each of the last ticks, to bring old neighbour values forward
        self._abuf_t = [-1] * hist

    def _forward(self, t: int, age: int) -> float:
        """How much omega_hat has changed from tick t to the state tick (t + age), for bringing an
        omega value of tick t (a neighbour's state, an eq. (9) sample) forward: the trend of the
        measurement path times age, plus the dynamical phase's feed-forward increments of those ticks
        exactly (so a modelled ramp starts and reverses at once)."""
        f = self._omdot * age
        if self.dynamic:
            ta = t % self._hist
            if self._abuf_t[ta] == t:
                f += self._asum - self._abuf[ta]
        return f

    # ------------------------------------------------------------------------ 1-3: inbox, pair samples
    def _use_sample(self, nb: _Nbr, t: int, w: complex, ref: int, pool: _Pool) -> None:
        """j's relative velocity sample w = v_Ci - v_Cj of tick t: into the pooled eq. (9) sums and j's
        pair estimator (whose first circle fit seeds omega_hat when nothing else has)."""
        dt = self.dt
        om = self.omega
        lag = ref - t
        omdt = om * dt
        back = complex(cos(omdt * lag), -sin(omdt * lag)) if lag else 1.0
        pe = nb.pair
        if pe.ready:
            zt = pe.z * back  # predicted z_ij at tick t (before this sample's correction)
            zz = zt.real * zt.real + zt.imag * zt.imag
            pool.num += zt.real * w.imag - zt.imag * w.real
            if lag:
                # eq. (9) of tick t measures omega of tick t: bring it to ref like j's omega state
                pool.fw += zz * self._forward(t, lag)
                if self.dynamic:
                    pool.late.append((t, zz))  # the dynamical phase's filter takes u as a delayed measurement
            pool.den += zz
            pe.sample(t, w, back, om, dt)
        else:
            pe.sample(t, w, back, om, dt)
            if pe.ready and not self.om_init:
                # bootstrap: the first fitted window's mean rate seeds omega_hat, so that the
                # prediction rotates z_ij and the gate opens (omega_hat = 0 would freeze both)
                self.om_init = True
                self._adopt_ph = True
                self.omega = pe.omega_fit

    def _hold_overtaken(self, nb: _Nbr, msg: StateMsg, t: int) -> None:
        """A message older than j's newest state (overtaken on a jittery link): its states are out of
        date, but its velocity is exact for tick t, so it is held for the pair estimator (_release)."""
        if t <= nb.rel or t in nb.pend or self._vtick[t % self._hist] != t:
            self.dropped_stale += 1  # replayed, or too late: its gap was already bridged
            if t < nb.last and t not in nb.pend:
                # a late arrival, not a replay: the link reorders; wait this long from now on
                depth = nb.last - t
                if depth > nb.hold:
                    nb.hold = depth if depth < _HOLD_MAX else _HOLD_MAX
            return
        try:
            vjx = msg.vx
            vjy = msg.vy
            chk = vjx + vjy
        except (TypeError, AttributeError):
            self.dropped_stale += 1
            return
        if chk - chk != 0.0:
            self.dropped_stale += 1
            return
        depth = nb.last - t
        if depth > nb.hold:
            nb.hold = depth if depth < _HOLD_MAX else _HOLD_MAX
        nb.pend[t] = complex(vjx, vjy)
        self._held = True

    def _take_inbox(self, tick: int, inbox: Sequence[StateMsg], decode: Decode | None,
                    pool: _Pool, dyn_in: list[DynamicMsg]) -> None:
        """Step 1: every message's states, and its velocity sample to ``_use_sample``."""
        if len(inbox) > 1:
            # (tick, sender) order: per-sender tick order matters, and a fixed order makes the
            # result independent of the arrival order within a tick (bit-identical replays)
            inbox = sorted(inbox, key=_by_tick)
        ref = tick - 1
        me = self.id
        hist = self._hist
        for msg in inbox:
            nb = self.nbrs.get(msg.sender)
            if nb is None:
                self.dropped_unknown += 1
                continue
            t = msg.tick
            if t > tick:
                self.dropped_stale += 1
                continue
            if t <= nb.last:
                self._hold_overtaken(nb, msg, t)
                continue
            # one try catches every kind of malformed payload at once
            try:
                sh = msg.shared
                s_om = sh["om"]
                s_ph = sh["ph"]
                yx = sh["yx"]
                yy = sh["yy"]
                s_ok = sh["oi"] > 0.0
                pz = msg.pair.get(me)
                if decode is None:
                    if pz is None:
                        zx = zy = fx = fy = 0.0
                    else:
                        zx, zy, fx, fy = pz
                else:
                    if pz is None:
                        zx = zy = fx = fy = 0.0
                        fl = None
                    else:
                        zx, zy, fx, fy, *fl = pz
                    # the dynamical states are checked on their own: taken even if the velocity is not
                    dyn_in.append(decode(msg.sender, t, msg.phase, sh, fl))
                vjx = msg.vx
                vjy = msg.vy
                chk = s_om + s_ph + yx + yy + zx + zy + fx + fy + vjx + vjy
            except (KeyError, TypeError, IndexError, AttributeError, ValueError):
                self.dropped_stale += 1  # malformed: counted with the unusable messages
                continue
            if chk - chk != 0.0:  # NaN or infinite somewhere
                self.dropped_stale += 1
                continue
            nb.last = t
            nb.om = s_om
            nb.om_ok = s_ok
            nb.ph = s_ph
            nb.y = complex(yx, yy)
            nb.zji = complex(zx, zy)
            nb.fji = complex(fx, fy)
            nb.st_t = t
            ts = t % hist
            if self._vtick[ts] != t:
                continue  # no own sample of that tick any more (too old)
            if nb.pend or (nb.hold and t != nb.rel + 1):
                # this link reorders and earlier samples may still be on their way: hold this one
                nb.pend[t] = complex(vjx, vjy)
                self._held = True
                continue
            nb.rel = t
            self._use_sample(nb, t, self.vbuf[ts] - complex(vjx, vjy), ref, pool)
        if self._held:  # some neighbour's samples are held back (a reordering link)
            held = False
            for nb in self._nlist:
                if nb.pend:
                    self._release(nb, ref, pool)
                    held = held or bool(nb.pend)
            self._held = held

    def _release(self, nb: _Nbr, ref: int, pool: _Pool) -> None:
        """Feed j's held-back velocities to its pair estimator in tick order: a sample goes once every
        earlier one has been used, or once it is ``nb.hold`` ticks older than j's newest state (the
        earlier ones are then lost)."""
        pend = nb.pend
        limit = nb.last - nb.hold
        for t in sorted(pend):
            if t != nb.rel + 1 and t > limit:
                break
            vj = pend.pop(t)
            nb.rel = t
            ts = t % self._hist
            if self._vtick[ts] != t:
                continue
            self._use_sample(nb, t, self.vbuf[ts] - vj, ref, pool)

    # ------------------------------------------------------------------------------------------ step
    def step(self, tick: int, vx: float, vy: float, inbox: Sequence[StateMsg], fb: DynamicFeedback,
             decode: Decode | None = None) -> KinematicTick:
        """One tick; ``fb`` is the dynamical phase's feedback of the previous tick, ``decode`` its
        message decoder (None without a dynamical phase)."""
        if tick <= self.last_tick:
            raise ValueError(f"ticks must increase: got {tick} after {self.last_tick}")
        self.last_tick = tick
        dt = self.dt
        hist = self._hist
        slot = tick % hist
        self.vbuf[slot] = complex(vx, vy)
        self._vtick[slot] = tick
        ref = tick - 1  # the tick the states refer to on entry

        pool = _Pool()
        dyn_in: list[DynamicMsg] = []
        self._take_inbox(tick, inbox, decode, pool, dyn_in)

        # 3-4. neighbour states: omega (low-pass consensus), body-frame angle phi (phase consensus),
        # z_i in that frame (centroid iteration in flow form with antisymmetric edge terms)
        om = self.omega
        omdt = om * dt  # "om * dt * k" parses as (om * dt) * k: hoisting it is exact
        ph = self.phi
        y = self.y
        eps_z = self._eps_z
        oms: list[float] = []  # initialised neighbours' omega states, brought to ref
        phs: list[float] = []  # their phi, brought to ref
        sflow = 0j  # sum_j F_ij, in neighbour order (a neighbour not heard from keeps its last flow)
        for nb in self._nlist:
            age = ref - nb.st_t
            if age > self._max_age:
                sflow += nb.flow
                continue
            nph = nb.ph
            if nb.om_ok:
                # j's values of tick ref - age, brought to ref (``_forward``)
                oms.append(nb.om + (self._forward(nb.st_t, age) if age else 0.0))
                phs.append(nph + omdt * age)
            zs = nb.z_sent
            zji = nb.zji
            if zs == 0j or zji == 0j:
                f = flow_step(nb.flow, nb.fji, eps_z, None)
            else:
                if age:
                    zji *= complex(cos(omdt * age), sin(omdt * age))
                # common edge frame: both ends rotate the edge term by the same angle -> antisymmetric
                a = -0.5 * (ph + nph + omdt * age)
                e = 0.5 * (zs - zji) * complex(cos(a), sin(a))
                # y_i += eps sum_j (y_j - y_i + e_ij) in flow form: y_i = -sum_j F_ij
                f = flow_step(nb.flow, nb.fji, eps_z, y - nb.y - e)
            nb.flow = f
            sflow += f
        cnt = len(oms)
        om_init = self.om_init
        adopt = cnt > 0 and (not om_init or self._adopt_ph)  # (re)initialised: take the neighbours' phase too
        self._adopt_ph = False
        if adopt and not om_init:
            # not seeded by an own fit yet: adopt the neighbours' mean instead of pulling them to 0
            self.om_init = om_init = True
            om = om + disagreement(om, oms) / cnt
            oms = []
        if pool.den > 0.0:
            u = pool.num / pool.den  # as measured: the estimate's omega_local and the dynamical phase's input
            # brought to tick ref for the consensus (the dynamical phase's filter takes u as it is, as a
            # delayed measurement of its samples' ticks)
            um = u + pool.fw / pool.den if pool.fw else u
            if fb.om_meas == fb.om_meas:
                # the dynamical phase's filter omega (DynamicsSpec.filter_omega): the pairs' angles are
                # dead-reckoned with omega_hat at high noise and eq. (9) would feed its lag back
                um = fb.om_meas
            b = self._beta * (um - om)
        else:
            um = None
            b = _NAN
            u = _NAN
        # (u_den > 0 only once a pair is ready, and a ready pair seeds omega_hat: om_init holds then)
        om_new = lowpass_step(om, oms, self._eps_om, self._beta, um) if om_init else 0.0
        if self.dynamic and om_init:
            # feed-forward of the dynamical filter's angular acceleration: without it omega_hat lags a
            # ramp by omega_dot * omega_tau, and phi, z_ij and z_i fall behind the body while omega ramps
            om_new += fb.alpha * dt
        if om_init and not adopt and b == b:
            # omega_hat's trend from its measurements, not from the consensus term (which would feed
            # back on itself); low-passed with the filter's time constant
            self._omdot = self._omdot + self._beta * (b - self._omdot)
        if self.dynamic:
            if om_init:
                self._asum = self._asum + fb.alpha * dt
            ta = tick % hist
            self._abuf[ta] = self._asum
            self._abuf_t[ta] = tick
        if self._nlist and not fb.hold_shape:
            self.y = y = -sflow  # y_i = -sum_j F_ij
        if adopt:
            ph = ph + disagreement(ph, phs) / cnt  # join the neighbours' body frame (y is still 0 then)
        else:
            ph = average_step(ph, phs, self._eps_ph)
        ph += om_new * dt
        self.phi = ph
        self.omega = om_new

        # 2. prediction of every z_ij to tick k
        rot = complex(cos(om_new * dt), sin(om_new * dt))
        ready = 0
        for nb in self._nlist:
            pe = nb.pair
            if pe.ready:
                ready += 1
            pe.predict(rot)
            nb.z_sent = pe.z
        self.trusted = ready == len(self._nlist) and ready > 0

        # 5. control
        target = None
        if om_init and self.dynamic and 0 <= self._boost_tick <= tick and fb.team_waiting:
            # the team is late: some pair has no circle fit yet. Spin faster until every agent is
            # ready (the flooded readiness mask is full): the same rule at every agent, no message
            target = self._boost_target
        wrench = self._ctl.wrench(tick, om_new, om_init, target)
        return KinematicTick(
            tick=tick,
            v=complex(vx, vy),
            u=u,
            u_den=pool.den,
            late=tuple(pool.late),
            omega=om_new,
            om_init=om_init,
            phi=ph,
            y=y,
            zi=y * complex(cos(ph), sin(ph)),
            pairs=tuple((nb.id, nb.z_sent, nb.flow) for nb in self._nlist),
            ready=ready,
            trusted=self.trusted,
            wrench=wrench,
            inbox=tuple(dyn_in),
            dropped_unknown=self.dropped_unknown,
            dropped_stale=self.dropped_stale,
        )
