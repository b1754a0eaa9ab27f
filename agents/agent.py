"""The pure agent core for the kinematic phase (paper 000 Sec. IV, blocks 1-6 of Fig. 2).

One :class:`AgentCore` per robot; :meth:`AgentCore.step` is a deterministic state machine
(tick, own measurement, neighbour messages) -> (message, wrench, estimate): no clock, socket or RNG.

Per tick k (all states refer to tick k-1 on entry and are predicted to tick k on exit):

1. inbox: drop unknown senders, duplicates and malformed messages (counted); process each sender's
   messages in tick order. A message of tick t carries the sender's measured velocity at t, paired
   with the agent's own measurement of the *same* tick from a ring buffer (older than the buffer: the
   velocity is not used, the states still are), so the pair estimator's inputs are exact, only late.
   A message overtaken by a newer one (jitter) gives its velocity only: once a link is seen to
   reorder (a late arrival), its samples are held until the earlier ones arrive or are ``hold`` ticks
   overdue, and fed in tick order (``_release``); dropping them cost ~1/3 of the samples at 0-5 ticks
   of jitter and biased |z_ij|.
2. z_ij (``agents.kinematic.PairEstimator``): circle fit of the integrated relative velocity for
   |z_ij|, angle tracked by rotation with omega_hat and corrected by the radial part of (v_Ci - v_Cj)/z_ij.
3. omega: eq. (9) with the corrected sign, evaluated with the *predicted* z_ij and pooled over
   the agent's pairs as a least-squares ratio u_i = sum_j z_ij x zdot_ij / sum_j |z_ij|^2 (the
   minimum-variance combination: each pair's noise on omega scales as 1/|z_ij|). It is unbiased at
   any |omega| (no gate needed), so omega_hat stays valid near 0. Then a low-pass consensus filter
   o_i += eps sum_j (o_j - o_i) + beta (u_i - o_i) (``agents.consensus.lowpass_step``): every
   agent measures the *same* omega, so the job is averaging noise over time and over the graph, not
   tracking heterogeneous inputs; unlike the first-order input dynamic consensus it time-averages
   the per-tick noise and forgets the errors of lost messages instead of keeping them for good.
   Delayed omega information -- a neighbour's o_j of tick ref - age, an eq. (9) sample of tick t --
   is brought to tick ref (``_forward``) by omega_hat's own trend (the beta-path increments,
   low-passed; not the consensus increments, which would feed back on themselves) plus the
   dynamical phase's feed-forward increments of those ticks, summed exactly from a ring buffer (a
   J-stage ramp starts and reverses at once). Without it the consensus pulls towards values ``age``
   ticks old and omega_hat lags a ramp by eps * degree * age / beta ticks (3.3 s at 100 ms delay),
   which turned the body frame away from the load and z_i with it. With fault-free links every age
   is 0 and the arithmetic is the undelayed one bit for bit.
4. z_i (Result 3, ref. [19]): y_i += eps sum_j (y_j - y_i + e_ij), e_ij = (z_ij - z_ji)/2 with the
   neighbour's own z_ji from its message, so the edge terms are antisymmetric and sum_i y_i stays 0.
   Two changes make it hold on a rotating load with imperfect links:
   - it runs in a body frame: x_i = e^{i phi_i} y_i, phi_i = integral of omega_hat kept in agreement
     by phase consensus, and each edge term is rotated into the frame (phi_i + phi_j)/2 that both
     ends compute alike. This is the rotation prediction of the pitfalls note (without it the
     iteration lags by tens of %), but rotating each x_i by its own omega_hat would make the sum
     random-walk (sum_i (omega_i - mean) x_i != 0; measured 0.07 m after 60 s);
   - it is written in flow form (flow-updating): y_i = -sum_j F_ij with
     F_ij = (F_ij - F_ji(latest received))/2 + eps (y_i - y_j - e_ij). With lost or delayed messages
     the plain form loses the sum for good (measured 1 m with a 3-tick delay); flows only carry the
     in-flight increments. Antisymmetrised as in ``agents.dynamic.FlowAverage``: with
     F_ij = -F_ji the asymmetry F_ij + F_ji left by one lost message flips sign every exchange and
     never decays (measured: sum z_i stuck at 9.5 mm after 30 % loss); the mean of the two ends
     removes it at the next exchange.

Wire content of :class:`StateMsg`: ``shared = {"om": omega state, "oi": 1.0 once it is
initialised else 0.0, "ph": phi_i (rad), "yx", "yy": y_i (m)}``,
``pair[j] = (z_ij_x, z_ij_y, F_ij_x, F_ij_y)`` (z_ij = 0, 0 while not estimated yet), ``phase`` = 0 spinning up,
1 regulating omega (once omega_hat exists, from an own circle fit or adopted from a neighbour).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import fields
from math import cos, sin
from operator import attrgetter, itemgetter

from agents import dynamic
from agents.control import KinematicControl
from agents.kinematic import PairEstimator
from agents.laws import LawInput
from config.agent_params import ControlSpec, DynamicsSpec, EstimatorSpec
from net.messages import Estimate, StateMsg, Wrench
from net.vocabulary import ESTIMATE_NAMES

_DYN_NAMES = ESTIMATE_NAMES[ESTIMATE_NAMES.index("J"):]
_KINEMATIC = dynamic.KINEMATIC  # the dynamical phase's stage while the team waits for kinematic readiness
_NO_DYN = dict.fromkeys(_DYN_NAMES, math.nan)

_HOLD_MAX = 16  # longest wait for a reordered velocity sample (ticks); well inside history_ticks
PHASE_SPINUP = 0
PHASE_REGULATE = 1

_by_tick = attrgetter("tick", "sender")
_get_kin = itemgetter("om", "ph", "yx", "yy", "oi")  # a neighbour's kinematic states, in one call


def _fast_factory(cls):  # type: ignore[no-untyped-def]
    """A positional constructor for a frozen, slotted dataclass that skips its generated __init__.

    Frozen dataclasses assign every field through object.__setattr__, which costs ~0.25 us per field;
    the outputs are built every tick. The fastest pure-Python way to fill the slots is a plain
    attribute store on a mutable twin class with the same slot layout, whose instance is then
    re-labelled as ``cls`` (``__class__`` assignment, allowed between identical layouts): the same
    resulting object (a test checks equality, type and fields against the normal constructor) at
    ~1/2 the cost of calling each slot descriptor. Falls back to the descriptors if the layouts
    differ, and to ``cls`` itself if it has no slots or a ``__post_init__``.
    """
    names = [f.name for f in fields(cls)]
    try:
        setters = tuple(cls.__dict__[nm].__set__ for nm in names)
    except (KeyError, AttributeError):
        return cls
    if getattr(cls, "__post_init__", None) is not None:
        return cls
    args = ", ".join(names)
    twin = type(f"_{cls.__name__}Fill", (), {"__slots__": tuple(cls.__slots__)})
    env = {"new": object.__new__, "cls": cls, "twin": twin, **{f"s{k}": st for k, st in enumerate(setters)}}
    swap = "def make({args}):\n    o = new(twin)\n{body}    o.__class__ = cls\n    return o\n".format(
        args=args, body="".join(f"    o.{nm} = {nm}\n" for nm in names)
    )
    exec(swap, env)  # noqa: S102 - generated from the dataclass's own field names
    try:
        env["make"](*range(len(names)))  # the layouts must match for the __class__ assignment
    except TypeError:
        slow = "def make({args}):\n    o = new(cls)\n{body}    return o\n".format(
            args=args, body="".join(f"    s{k}(o, {nm})\n" for k, nm in enumerate(names))
        )
        exec(slow, env)  # noqa: S102
    return env["make"]


_new_state = _fast_factory(StateMsg)
_new_estimate = _fast_factory(Estimate)
_new_wrench = _fast_factory(Wrench)
_new = object.__new__
_NAN = math.nan


def _build_estimate(
    tick: int, agent: int, stage: int, om: float, u: float, y: complex, ph: float,
    ready: int, d_unknown: int, d_stale: int, pair: dict[int, tuple[float, ...]], dyn: tuple | None,
) -> Estimate:
    """The :class:`Estimate` of one tick, from the values :meth:`AgentCore.step` snapshots.

    ``pair`` is the tick's outgoing ``StateMsg.pair`` (z_ij_x, z_ij_y, F_ij_x, F_ij_y, then the dynamical
    phase's flows if any; only the first two are read): it already
    holds every z_ij estimate, in neighbour order; ``dyn`` the dynamical phase's snapshot
    (``DynamicPhase.snapshot``), None without it.
    """
    x = y * complex(cos(ph), sin(ph))  # z_i in the world frame
    return _new_estimate(
        tick,
        agent,
        {
            "phase": float(stage),
            "omega": om,
            "omega_local": u,
            "zi_x": x.real,
            "zi_y": x.imag,
            "pairs_ready": ready + 0.0,
            "dropped_unknown": d_unknown + 0.0,
            "dropped_stale": d_stale + 0.0,
            **(_NO_DYN if dyn is None else dynamic.estimates(dyn)),
        },
        {j: (p[0], p[1]) for j, p in pair.items()},
    )


class StepResult:
    """One tick's outputs: ``state`` (to the neighbours), ``wrench`` (to the plant), ``estimate``.

    Behaves like the dataclass ``StepResult(state, wrench, estimate)`` (same constructor, equality
    and repr), but ``estimate`` is built on first access from a snapshot that ``step`` takes: most
    ticks nobody reads it (recording and publishing are decimated), and its two dicts and three
    objects were ~10 % of a step. The snapshot holds immutable values only, so a late access sees
    exactly the tick's estimate.
    """

    __slots__ = ("_estimate", "_snap", "state", "wrench")

    def __init__(self, state: StateMsg, wrench: Wrench, estimate: Estimate) -> None:
        self.state = state
        self.wrench = wrench
        self._estimate = estimate
        self._snap: tuple | None = None

    @property
    def estimate(self) -> Estimate:
        est = self._estimate
        if est is None:
            est = self._estimate = _build_estimate(*self._snap)  # type: ignore[misc]
            self._snap = None
        return est

    def __eq__(self, other: object) -> bool:
        if other.__class__ is not self.__class__:
            return NotImplemented
        return (self.state, self.wrench, self.estimate) == (other.state, other.wrench, other.estimate)  # type: ignore[attr-defined]

    __hash__ = None  # type: ignore[assignment]  # mutable, like the eq=True dataclass it replaces

    def __repr__(self) -> str:
        return f"StepResult(state={self.state!r}, wrench={self.wrench!r}, estimate={self.estimate!r})"


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


class AgentCore:
    """Agent i's kinematic-phase estimator and controller (see the module docstring).

    ``step`` is the hot path (~12 us with two neighbours on the 2-core dev machine): it reads its
    constants and state into locals once, keeps the arithmetic expressions (and so the results) of
    the straightforward code bit for bit, and inlines the small helpers (pair prediction, control
    law).
    """

    __slots__ = (
        "_adopt_ph",
        "_beta",
        "_ctl",
        "_dyn",
        "_eps_om",
        "_eps_ph",
        "_eps_z",
        "_hist",
        "_max_age",
        "_nbrs",
        "_nlist",
        "_om_init",
        "_tick",
        "_vbuf",
        "_vtick",
        "_wr",
        "_boost_tick",
        "_boost_target",
        "_omdot",
        "_held",
        "_asum",
        "_abuf",
        "_abuf_t",
        "dropped_stale",
        "dropped_unknown",
        "dt",
        "id",
        "n",
        "omega",
        "phi",
        "sigma_v",
        "spec",
        "trusted",
        "y",
    )

    def __init__(
        self,
        agent_id: int,
        neighbours: Sequence[int],
        n: int,
        dt: float,
        sigma_v: float,
        estimator: EstimatorSpec,
        control: ControlSpec,
        dynamics: DynamicsSpec | None = None,
        law: Callable[[LawInput], Sequence[float]] | None = None,
    ) -> None:
        """``law``: a control law of the user's (agents/laws.py), called where the dynamical phase allows."""
        if agent_id in neighbours:
            raise ValueError("an agent cannot be its own neighbour")
        self.id = int(agent_id)
        self.n = int(n)
        self.dt = float(dt)
        sig = float(estimator.sigma_v if estimator.sigma_v is not None else sigma_v)
        self.sigma_v = sig
        self.spec = estimator
        self._ctl = ctl = KinematicControl(control, dt)
        # the control law's constants, for the inlined KinematicControl.wrench (negation is exact)
        self._wr = (ctl._switch, ctl._fx, ctl._fy, -ctl._fx, -ctl._fy, ctl._spin, ctl._target, ctl._k, ctl._tmax)
        # the target while the team waits for a late pair (ControlSpec.omega_boost; dynamical phase only)
        self._boost_tick = round(control.boost_after_s / dt) if control.omega_boost > 0 else -1
        self._boost_target = (1.0 if ctl._spin >= 0.0 else -1.0) * max(control.omega_boost, control.omega_target)
        nb_ids = sorted(set(int(j) for j in neighbours))
        self._nbrs: dict[int, _Nbr] = {}
        for j in nb_ids:
            pe = PairEstimator(
                dt=dt,
                sigma_v=sig,
                fit_arc=estimator.fit_arc,
                fit_min_ticks=estimator.fit_min_ticks,
                fit_max_ticks=estimator.fit_max_ticks,
                fit_check_ticks=estimator.fit_check_ticks,
                max_gap_ticks=estimator.max_gap_ticks,
                angle_walk=estimator.angle_walk,
                gate_snr=estimator.gate_snr,
                angle_meas=estimator.angle_meas,
            )
            self._nbrs[j] = _Nbr(j, pe)
        self._nlist = list(self._nbrs.values())
        hist = estimator.history_ticks
        self._hist = hist
        self._vbuf = [0j] * hist
        self._vtick = [-1] * hist
        self._max_age = estimator.max_age_ticks
        self._beta = min(1.0, dt / estimator.omega_tau)
        self._eps_om = estimator.omega_eps
        self._eps_z = estimator.centroid_eps
        self.omega = 0.0  # omega_hat
        self._om_init = False  # omega_hat seeded from a circle fit (or from a neighbour's value)
        self.y = 0j  # z_i in the agents' common body frame: x = e^{i phi} y
        self.phi = 0.0  # body-frame angle, integral of omega_hat kept in agreement by consensus
        self._adopt_ph = False
        self._eps_ph = estimator.centroid_eps
        self.trusted = False
        self.dropped_unknown = 0
        self.dropped_stale = 0
        self._tick = -1
        self._omdot = 0.0  # omega_hat's own trend per tick (its measurement path, low-passed)
        self._held = False  # some _Nbr.pend is not empty
        self._asum = 0.0  # sum of the dynamical phase's feed-forward increments alpha dt so far (rad/s)
        self._abuf = [0.0] * hist  # _asum at each of the last ticks, to bring old neighbour values forward
        self._abuf_t = [-1] * hist
        self._dyn = None
        if dynamics is not None and dynamics.algorithm != "none":
            self._dyn = dynamic.DynamicPhase(self.id, nb_ids, self.n, self.dt, sig, dynamics, hist,
                                             law=law, law_ref=control.law)
        elif law is not None:
            raise ValueError("a control law needs the dynamical phase (dynamics.algorithm sequential or background)")

    @property
    def x(self) -> complex:
        """z_i estimate (world frame); derived on demand, the step itself only needs y and phi."""
        ph = self.phi
        return self.y * complex(cos(ph), sin(ph))

    def _forward(self, t: int, age: int) -> float:
        """How much omega_hat has changed from tick t to the state tick (t + age), for bringing an
        omega value of tick t (a neighbour's state, an eq. (9) sample) forward: the trend of the
        measurement path times age, plus the dynamical phase's feed-forward increments of those ticks
        exactly (so a modelled ramp starts and reverses at once)."""
        f = self._omdot * age
        if self._dyn is not None:
            ta = t % self._hist
            if self._abuf_t[ta] == t:
                f += self._asum - self._abuf[ta]
        return f

    def _release(
        self, nb: _Nbr, ref: int, om: float, u_num: float, u_den: float, u_fw: float
    ) -> tuple[float, float, float, float]:
        """Feed j's held-back velocities to its pair estimator in tick order.

        A sample goes once every earlier one has been used, or once it is ``nb.hold`` ticks older than
        j's newest state (the earlier ones are then lost). The same arithmetic as the in-order path of
        ``step``; returns the updated (u_num, u_den, u_fw, omega_hat).
        """
        pend = nb.pend
        hist = self._hist
        vbuf = self._vbuf
        vtick = self._vtick
        dt = self.dt
        pe = nb.pair
        limit = nb.last - nb.hold
        for t in sorted(pend):
            if t != nb.rel + 1 and t > limit:
                break
            vj = pend.pop(t)
            nb.rel = t
            ts = t % hist
            if vtick[ts] != t:
                continue
            w = vbuf[ts] - vj
            lag = ref - t
            omdt = om * dt
            back = complex(cos(omdt * lag), -sin(omdt * lag)) if lag else 1.0
            if pe.ready:
                zt = pe.z * back
                zz = zt.real * zt.real + zt.imag * zt.imag
                u_num += zt.real * w.imag - zt.imag * w.real
                if lag:
                    u_fw += zz * self._forward(t, lag)
                    if self._dyn is not None:
                        self._dyn.note_late(t, zz)
                u_den += zz
                pe.sample(t, w, back, om, dt)
            else:
                pe.sample(t, w, back, om, dt)
                if pe.ready and not self._om_init:
                    self._om_init = True  # bootstrap, as in step
                    self._adopt_ph = True
                    self.omega = om = pe.omega_fit
        return u_num, u_den, u_fw, om

    # ------------------------------------------------------------------------------------------ step
    def step(self, tick: int, vx: float, vy: float, inbox: Sequence[StateMsg]) -> StepResult:
        if tick <= self._tick:
            raise ValueError(f"ticks must increase: got {tick} after {self._tick}")
        self._tick = tick
        dt = self.dt
        hist = self._hist
        vbuf = self._vbuf
        vtick = self._vtick
        slot = tick % hist
        vbuf[slot] = complex(vx, vy)
        vtick[slot] = tick
        ref = tick - 1  # the tick the states refer to on entry
        om = self.omega
        omdt = om * dt  # "om * dt * k" below parses as (om * dt) * k: hoisting it is exact

        # 1-3. inbox: pair samples and the local omega measurement -------------------------------
        u_num = 0.0
        u_fw = 0.0  # sum of |z|^2-weighted corrections that bring late samples' omega to tick ref
        u_den = 0.0
        if len(inbox) > 1:
            # (tick, sender) order: per-sender tick order matters, and a fixed order makes the
            # result independent of the arrival order within a tick (bit-identical replays)
            if len(inbox) == 2:
                m0, m1 = inbox
                if m1.tick < m0.tick or (m1.tick == m0.tick and m1.sender < m0.sender):
                    inbox = (m1, m0)
            else:
                inbox = sorted(inbox, key=_by_tick)
        nbrs = self._nbrs
        me = self.id
        dyn = self._dyn
        for msg in inbox:
            nb = nbrs.get(msg.sender)
            if nb is None:
                self.dropped_unknown += 1
                continue
            t = msg.tick
            if t > tick:
                self.dropped_stale += 1
                continue
            if t <= nb.last:
                # older than j's newest state (overtaken on a jittery link): its states are out of date,
                # but its velocity is exact for tick t -- hold it for the pair estimator (_release)
                if t <= nb.rel or t in nb.pend or vtick[t % hist] != t:
                    self.dropped_stale += 1  # replayed, or too late: its gap was already bridged
                    if t < nb.last and t not in nb.pend:
                        # a late arrival, not a replay: the link reorders; wait this long from now on
                        depth = nb.last - t
                        if depth > nb.hold:
                            nb.hold = depth if depth < _HOLD_MAX else _HOLD_MAX
                    continue
                try:
                    vjx = msg.vx
                    vjy = msg.vy
                    chk = vjx + vjy
                except (TypeError, AttributeError):
                    self.dropped_stale += 1
                    continue
                if chk - chk != 0.0:
                    self.dropped_stale += 1
                    continue
                depth = nb.last - t
                if depth > nb.hold:
                    nb.hold = depth if depth < _HOLD_MAX else _HOLD_MAX
                nb.pend[t] = complex(vjx, vjy)
                self._held = True
                continue
            # try costs nothing on the normal path (3.11 zero-cost exceptions) and catches every
            # kind of malformed payload at once, cheaper than checking keys and types one by one
            try:
                sh = msg.shared
                s_om, s_ph, yx, yy, s_ok = _get_kin(sh)
                s_ok = s_ok > 0.0
                pz = msg.pair.get(me)
                if dyn is None:
                    if pz is None:
                        zx = zy = fx = fy = 0.0
                    else:
                        zx, zy, fx, fy = pz
                else:
                    if pz is None:
                        zx = zy = fx = fy = 0.0
                        fl = dynamic.NO_FLOWS
                    else:
                        zx, zy, fx, fy, *fl = pz
                    dyn.receive(msg.sender, t, msg.phase, sh, fl)
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
            if vtick[ts] != t:
                continue  # no own sample of that tick any more (too old)
            if nb.pend or (nb.hold and t != nb.rel + 1):
                # this link reorders and earlier samples may still be on their way: hold this one
                nb.pend[t] = complex(vjx, vjy)
                self._held = True
                continue
            nb.rel = t
            w = vbuf[ts] - complex(vjx, vjy)
            lag = ref - t
            back = complex(cos(omdt * lag), -sin(omdt * lag)) if lag else 1.0
            pe = nb.pair
            if pe.ready:
                zt = pe.z * back  # predicted z_ij at tick t (before this sample's correction)
                zz = zt.real * zt.real + zt.imag * zt.imag
                u_num += zt.real * w.imag - zt.imag * w.real
                if lag:
                    # eq. (9) of tick t measures omega of tick t: bring it to ref like j's omega state
                    u_fw += zz * self._forward(t, lag)
                    if dyn is not None:
                        dyn.note_late(t, zz)  # the dynamical phase's filter takes u as a delayed measurement
                u_den += zz
                pe.sample(t, w, back, om, dt)
            else:
                pe.sample(t, w, back, om, dt)
                if pe.ready and not self._om_init:
                    # bootstrap: the first fitted window's mean rate seeds omega_hat, so that the
                    # prediction rotates z_ij and the gate opens (omega_hat = 0 would freeze both)
                    self._om_init = True
                    self._adopt_ph = True
                    self.omega = om = pe.omega_fit
                    omdt = om * dt

        if self._held:  # some neighbour's samples are held back (a reordering link)
            held = False
            for nb in self._nlist:
                if nb.pend:
                    u_num, u_den, u_fw, om = self._release(nb, ref, om, u_num, u_den, u_fw)
                    omdt = om * dt
                    held = held or bool(nb.pend)
            self._held = held

        # 4-5. neighbour states: omega (low-pass consensus), body-frame angle phi (phase consensus),
        # z_i in that frame (centroid iteration with antisymmetric edge terms) ----------------------
        nlist = self._nlist
        max_age = self._max_age
        ph = self.phi
        y = self.y
        omdot = self._omdot
        asum = self._asum
        acc = 0.0
        cnt = 0
        accp = 0.0
        eps_z = self._eps_z
        sflow = 0j  # sum_j F_ij, in neighbour order (a neighbour not heard from keeps its last flow)
        for nb in nlist:
            age = ref - nb.st_t
            if age > max_age:
                sflow += nb.flow
                continue
            nph = nb.ph
            if nb.om_ok:
                # j's value of tick ref - age, brought to ref (``_forward``)
                acc += nb.om + (self._forward(nb.st_t, age) if age else 0.0) - om
                cnt += 1
                accp += (nph + omdt * age) - ph
            zs = nb.z_sent
            zji = nb.zji
            if zs == 0j or zji == 0j:
                f = 0.5 * (nb.flow - nb.fji)
            else:
                if age:
                    zji *= complex(cos(omdt * age), sin(omdt * age))
                # common edge frame: both ends rotate the edge term by the same angle -> antisymmetric
                a = -0.5 * (ph + nph + omdt * age)
                e = 0.5 * (zs - zji) * complex(cos(a), sin(a))
                # flow form of y_i += eps sum_j (y_j - y_i + e_ij), antisymmetrised:
                # F_ij = (F_ij - F_ji)/2 + eps (y_i - y_j - e_ij)
                f = 0.5 * (nb.flow - nb.fji) + eps_z * (y - nb.y - e)
            nb.flow = f
            sflow += f
        om_init = self._om_init
        adopt = False
        if cnt and (not om_init or self._adopt_ph):
            adopt = True  # (re)initialised this tick: take the neighbours' phase too
            if not om_init:
                # not seeded by an own fit yet: adopt the neighbours' mean instead of pulling them to 0
                self._om_init = om_init = True
                om = om + acc / cnt
                acc = 0.0
        self._adopt_ph = False
        if om_init:
            om_new = om + self._eps_om * acc
        else:
            om_new = 0.0
        if u_den > 0.0:
            u = u_num / u_den  # as measured: the estimate's omega_local and the dynamical phase's input
            # brought to tick ref for the filter (the dynamical phase's Kalman filter takes u as it is, as a
            # delayed measurement of its samples' ticks, note_late: brought forward with its own modelled
            # acceleration here it confirmed its own J, measured 2.0 vs 1.8 %)
            um = u + u_fw / u_den if u_fw else u
            if dyn is not None and dyn.om_meas == dyn.om_meas:
                # the dynamical phase's filter from its restart on (DynamicsSpec.filter_omega): the pairs'
                # angles are dead-reckoned with omega_hat at high noise and eq. (9) then fed its lag back
                um = dyn.om_meas
            b = self._beta * (um - om)
            om_new += b
        else:
            b = _NAN
            u = _NAN
        if dyn is not None and om_init:
            # feed-forward of the dynamical filter's angular acceleration (1/J_hat times the modelled
            # torque): without it omega_hat lags a ramp by omega_dot * omega_tau, and phi, z_ij and
            # z_i fall behind the body while omega ramps (the J stage: EEC rose to ~1 m^2)
            om_new += dyn.alpha * dt
        if om_init and not adopt and b == b:
            # omega_hat's trend from its measurements, not from the consensus term (which would feed
            # back on itself); low-passed with the filter's time constant
            self._omdot = omdot + self._beta * (b - omdot)
        if dyn is not None:
            if om_init:
                self._asum = asum = asum + dyn.alpha * dt
            ta = tick % hist
            self._abuf[ta] = asum
            self._abuf_t[ta] = tick
        if nlist and (dyn is None or dyn.q_held is None):
            # (held, like the dynamical phase's q_i, once done under a law or braking that may stop the
            # rotation: z_i is observable only while the load turns)
            self.y = y = -sflow  # y_i = -sum_j F_ij
        if adopt:
            ph += accp / cnt  # join the neighbours' body frame (y is still 0 then)
        else:
            ph += self._eps_ph * accp
        ph += om_new * dt
        self.phi = ph
        self.omega = om_new
        rot = complex(cos(om_new * dt), sin(om_new * dt))
        pairs_msg: dict[int, tuple[float, ...]] = {}
        ready = 0
        for nb in nlist:
            pe = nb.pair
            if pe.ready:  # prediction to tick k (PairEstimator.predict, inlined)
                ready += 1
                pe.z = z = pe.z * rot
                pe._p += pe._q
            else:
                z = pe.z
            nb.z_sent = z
            if dyn is None:  # with the dynamical phase the entries are built once its flows are updated
                f = nb.flow
                pairs_msg[nb.id] = (z.real, z.imag, f.real, f.imag)
        self.trusted = ready == len(nlist) and ready > 0

        # 6. control (KinematicControl.wrench, inlined), outputs -------------------------------------
        switch, cfx, cfy, cfx_neg, cfy_neg, spin, target, k_om, tmax = self._wr
        if (tick // switch) & 1:
            fx, fy = cfx_neg, cfy_neg
        else:
            fx, fy = cfx, cfy
        if om_init:  # omega_hat exists: stop spinning up, regulate on it
            if dyn is not None and 0 <= self._boost_tick <= tick and dyn.stage == _KINEMATIC \
                    and dyn.barrier.mask != dyn.barrier.full:
                # the team is late: some pair has no circle fit yet. Spin faster until every agent is
                # ready (the flooded readiness mask is full): the same rule at every agent, no message
                target = self._boost_target
            tau = k_om * (target - om_new)
            if tau > tmax:
                tau = tmax
            elif tau < -tmax:
                tau = -tmax
        else:
            tau = spin
        i = me
        shared = {"om": om_new, "oi": 1.0 if om_init else 0.0, "ph": ph, "yx": y.real, "yy": y.imag}
        stage = PHASE_REGULATE if om_init else PHASE_SPINUP
        dyn_snap = None
        if dyn is not None:
            fx, fy, tau = dyn.step(
                tick, complex(vx, vy), u, u_den, om_new, ph, y * complex(cos(ph), sin(ph)), self.trusted, om_init,
                (fx, fy, tau),
            )
            stage = dyn.stage
            dyn.shared(shared)
            # (z_ij, F_ij, the dynamical flows to j); the estimate reads only the first two, so the
            # same dict serves it (one dict and tuple per neighbour, not two)
            flows_to = dyn.flows_to
            for nb in nlist:
                z = nb.z_sent
                f = nb.flow
                pairs_msg[nb.id] = (z.real, z.imag, f.real, f.imag, *flows_to(nb.id))
            dyn_snap = dyn.snapshot()
        pairs_est = pairs_msg
        res = _new(StepResult)
        res.state = _new_state(tick, i, vx, vy, stage, shared, pairs_msg)
        res.wrench = _new_wrench(tick, i, fx, fy, tau)
        res._estimate = None  # built on first access (StepResult.estimate)
        res._snap = (tick, i, stage, om_new, u, y, ph, ready, self.dropped_unknown, self.dropped_stale, pairs_est, dyn_snap)
        return res
