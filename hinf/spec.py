"""Spec for the cooperative H-infinity estimator design of paper 003 (Wu, Ugrinovskii, Allgöwer).

The spec names fields after the paper's symbols so a reader can check a file against the paper:
agents (1) x_k' = A_k x_k + B_k u_k + B~_k xi_k, y_k = C_k x_k; relative measurements
z_kj = y_j - y_k + omega eta_kj on every edge (j -> k). Loading reports errors as
``FILE: field.path: message`` because specs are hand-written matrices and a wrong shape is the
common mistake.
"""
from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from config.scenario import LinkSpec

Matrix = list[list[float]]


class SpecError(ValueError):
    """A spec file that cannot be used; the message names the file and the field."""


def _mat(value: Matrix, field: str) -> np.ndarray:
    """Rectangular, finite, non-empty 2-D matrix or a ValueError naming what is wrong."""
    if not value or not all(isinstance(r, list) for r in value):
        raise ValueError(f"{field} must be a non-empty list of rows")
    widths = {len(r) for r in value}
    if len(widths) != 1 or 0 in widths:
        raise ValueError(f"{field} rows must all have the same non-zero length, got {sorted(widths)}")
    m = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(m)):
        raise ValueError(f"{field} has non-finite entries")
    return m


class AgentSpec(BaseModel):
    """One agent k of (1)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    name: str = Field(description="agent id used in the edge list")
    A: Matrix = Field(description="A_k: n_k x n_k state matrix")
    B: Matrix | None = Field(None, description="B_k: n_k x m_k control input matrix (needed for sync)")
    Bt: Matrix = Field(description="B~_k: n_k x d_k disturbance (xi_k) input matrix")
    C: Matrix = Field(description="C_k: r x n_k output matrix; only y_j - y_k is ever measured")
    W: Matrix | None = Field(None, description="W_k: n_k x n_k weight on agent k's own estimation error "
                             "(W^(k) = diag(W_k, 0)); default identity")
    pi: float = Field(0.025, gt=0, description="pi_k: coupling margin of the LMIs (6), > 0")
    Pi: Matrix | None = Field(None, description="Pi_k: n_k x nu solution of the Francis equations (12)")
    Lambda: Matrix | None = Field(None, description="Lambda_k: m_k x nu solution of the Francis equations (12)")
    R: Matrix | None = Field(None, description="R_k: n_k x n_k regulation-error weight of (13)/(14); default I")

    @model_validator(mode="after")
    def _shapes(self) -> AgentSpec:
        a = _mat(self.A, "A")
        n = a.shape[0]
        if a.shape != (n, n):
            raise ValueError(f"A must be square, got {a.shape}")
        checks = {"Bt": (n, None), "C": (None, n), "B": (n, None), "W": (n, n), "R": (n, n), "Pi": (n, None)}
        for fname, (rows, cols) in checks.items():
            v = getattr(self, fname)
            if v is None:
                continue
            m = _mat(v, fname)
            if rows is not None and m.shape[0] != rows:
                raise ValueError(f"{fname} must have {rows} rows (n_k), got {m.shape[0]}")
            if cols is not None and m.shape[1] != cols:
                raise ValueError(f"{fname} must have {cols} columns (n_k), got {m.shape[1]}")
        for fname in ("W", "R"):
            v = getattr(self, fname)
            if v is not None:
                m = np.asarray(v)
                if not np.allclose(m, m.T) or np.linalg.eigvalsh((m + m.T) / 2).min() < -1e-12:
                    raise ValueError(f"{fname} must be symmetric positive semi-definite")
        if self.Lambda is not None:
            lam = _mat(self.Lambda, "Lambda")
            if self.B is None:
                raise ValueError("Lambda given without B")
            if lam.shape[0] != np.asarray(self.B).shape[1]:
                raise ValueError(f"Lambda must have m_k={np.asarray(self.B).shape[1]} rows, got {lam.shape[0]}")
        return self


class SyncSpec(BaseModel):
    """Synchronization design of Theorem 3 (internal model (10), controller (11))."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    S: Matrix = Field(description="S: nu x nu internal-model (exosystem) matrix, sigma(S) on the imaginary axis")
    Gamma: Matrix = Field(description="Gamma: r x nu output map of the exosystem, C_k Pi_k = Gamma")
    mu: float = Field(gt=0, description="mu: disturbance attenuation level in the Riccati equation (14)")
    lam: float = Field(gt=0, description="lambda: control weight in (14); H_k = -B_k^T X_k / lambda^2")

    @model_validator(mode="after")
    def _shapes(self) -> SyncSpec:
        s = _mat(self.S, "S")
        if s.shape[0] != s.shape[1]:
            raise ValueError(f"S must be square, got {s.shape}")
        g = _mat(self.Gamma, "Gamma")
        if g.shape[1] != s.shape[0]:
            raise ValueError(f"Gamma must have nu={s.shape[0]} columns, got {g.shape[1]}")
        return self


class DisturbanceSpec(BaseModel):
    """Disturbances xi_k and eta_kj of a run (coload hinf run); drawn from the run seed, held over a tick."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    kind: Literal["none", "white", "worst"] = Field(
        "none", description="none: xi = eta = 0; white: Gaussian samples held over each tick; worst: the "
        "input direction (and frequency) at which the designed error network's gain peaks, as a sinusoid")
    xi_std: float = Field(1.0, ge=0, description="white: std of every component of xi_k")
    eta_std: float = Field(1.0, ge=0, description="white: std of every component of eta_kj")
    amplitude: float = Field(1.0, ge=0, description="worst: Euclidean norm of the stacked input [xi scaled; eta]")
    t_on: float = Field(0.0, ge=0, description="disturbances act from this time (s)")
    t_off: float | None = Field(None, gt=0, description="disturbances stop at this time (s); default: never")


class HinfTimingSpec(BaseModel):
    """Waits of the hinf daemons; a timeout is counted in summary.json, never fatal."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    startup_timeout_s: float = Field(30.0, gt=0, description="the simulator waits this long for every estimator")
    input_timeout_s: float = Field(2.0, gt=0, description="lockstep: the simulator waits this long for u_k "
                                   "(then holds the last one)")
    neighbour_timeout_s: float = Field(2.0, gt=0, description="lockstep: an estimator waits this long for a "
                                       "neighbour's estimate (then holds the last one)")


class RunSection(BaseModel):
    """How `coload hinf run` simulates the spec: tick, length, seed, initial states, disturbances, links."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    dt: float = Field(0.01, gt=0, description="tick (s): the plant is discretised exactly for it, the "
                      "estimators sample z_kj once per tick")
    duration: float = Field(30.0, gt=0, description="simulated time (s)")
    seed: int = Field(0, ge=0, description="run seed: initial states, disturbances and link faults derive from it")
    mode: Literal["lockstep", "realtime"] = Field(
        "lockstep", description="lockstep: the simulator is the clock (reproducible); realtime: wall-clock pace")
    control: bool | None = Field(None, description="run the synchronization controllers (10)-(11) with the "
                                 "Theorem 3 gains; default: whenever the spec has [sync]. false: u_k = 0")
    x0: list[list[float]] | None = Field(None, description="initial agent states x_k(0), one list per agent; "
                                         "default: drawn N(0, x0_std^2)")
    x0_std: float = Field(1.0, ge=0, description="std of the drawn initial states (0: start at rest)")
    zeta0: list[list[float]] | None = Field(None, description="initial internal-model states zeta_k(0), one list "
                                            "per agent; default: drawn N(0, zeta0_std^2); every daemon knows them")
    zeta0_std: float = Field(1.0, ge=0, description="std of the drawn zeta_k(0)")
    disturbance: DisturbanceSpec = Field(DisturbanceSpec(), description="xi_k and eta_kj of the run")
    link: LinkSpec = Field(LinkSpec(), description="fault model of every estimator-to-estimator link "
                           "(agents numbered 0..N-1 in spec order)")
    timing: HinfTimingSpec = Field(HinfTimingSpec(), description="daemon waits")

    @model_validator(mode="after")
    def _at_least_one_tick(self) -> RunSection:
        if round(self.duration / self.dt) < 1:
            raise ValueError(f"duration {self.duration} s is shorter than one tick dt = {self.dt} s")
        return self

    @property
    def ticks(self) -> int:
        return round(self.duration / self.dt)


class HinfSpec(BaseModel):
    """Whole design problem: agents, directed graph, and the design constants of (6)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    name: str = Field("hinf", description="label of the design and of its runs")
    omega: float = Field(gt=0, description="omega: weight of the measurement noise eta in z_kj")
    alpha: float = Field(0.0, ge=0, description="alpha: guaranteed decay rate, V' <= -alpha V without disturbance")
    agents: list[AgentSpec] = Field(min_length=1, description="the agents of (1), in the order that numbers them 0..N-1")
    edges: list[tuple[str, str]] = Field(description="[j, k]: agent k measures z_kj = y_j - y_k and hears from j")
    sync: SyncSpec | None = Field(None, description="Theorem 3 synchronization design; omit for estimation only")
    run: RunSection = Field(RunSection(), description="simulation of the designed network (coload hinf run)")

    @field_validator("agents")
    @classmethod
    def _unique(cls, v: list[AgentSpec]) -> list[AgentSpec]:
        names = [a.name for a in v]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"duplicate agent names {dup}")
        return v

    @model_validator(mode="after")
    def _graph(self) -> HinfSpec:
        rs = {np.asarray(a.C).shape[0] for a in self.agents}
        if len(rs) != 1:
            raise ValueError(f"agents: all C_k must have the same number of rows r, got {sorted(rs)}")
        names = {a.name for a in self.agents}
        seen = set()
        for i, (j, k) in enumerate(self.edges):
            for who in (j, k):
                if who not in names:
                    raise ValueError(f"edges[{i}]: unknown agent {who!r}")
            if j == k:
                raise ValueError(f"edges[{i}]: self-loop on {j!r}")
            if (j, k) in seen:
                raise ValueError(f"edges[{i}]: duplicate edge {j!r} -> {k!r}")
            seen.add((j, k))
        if self.sync is not None:
            nu = len(self.sync.S)
            r = rs.pop()
            if len(self.sync.Gamma) != r:
                raise ValueError(f"sync.Gamma must have r={r} rows, got {len(self.sync.Gamma)}")
            for a in self.agents:
                if a.B is None:
                    raise ValueError(f"agents: agent {a.name!r} needs B for the sync design")
                for f in ("Pi", "Lambda"):
                    v = getattr(a, f)
                    if v is not None and len(v[0]) != nu:
                        raise ValueError(f"agents: agent {a.name!r} {f} must have nu={nu} columns")
        self._check_run()
        return self

    def _check_run(self) -> None:
        """Initial states, control switch and partitions of [run] against the agents and the graph."""
        run, N = self.run, len(self.agents)
        if run.x0 is not None:
            if len(run.x0) != N:
                raise ValueError(f"run.x0: give one state per agent ({N}), got {len(run.x0)}")
            for a, x in zip(self.agents, run.x0):
                if len(x) != len(a.A):
                    raise ValueError(f"run.x0: agent {a.name!r} has n_k={len(a.A)} states, got {len(x)}")
        if run.control and self.sync is None:
            raise ValueError("run.control: the controllers need a [sync] section")
        if run.zeta0 is not None:
            nu = len(self.sync.S) if self.sync is not None else 0
            if len(run.zeta0) != N or any(len(z) != nu for z in run.zeta0):
                raise ValueError(f"run.zeta0: give one state of length nu={nu} per agent ({N})")
        d = run.disturbance
        if d.t_off is not None and d.t_off <= d.t_on:
            raise ValueError(f"run.disturbance.t_off ({d.t_off}) must be after t_on ({d.t_on})")
        idx = {a.name: i for i, a in enumerate(self.agents)}
        edges = {frozenset((idx[j], idx[k])) for j, k in self.edges}
        for p, part in enumerate(run.link.partitions):
            ids = [i for e in part.cut or () for i in e] + [i for g in part.groups or () for i in g]
            if any(i >= N for i in ids):
                raise ValueError(f"run.link.partitions: partition {p} names an agent id >= {N} (ids are 0..{N - 1})")
            for i, j in part.cut or ():
                if frozenset((i, j)) not in edges:
                    raise ValueError(f"run.link.partitions: partition {p} cuts [{i}, {j}], not an edge")

    @property
    def control(self) -> bool:
        """Whether a run closes the loop with the synchronization controllers."""
        return self.sync is not None if self.run.control is None else self.run.control


def _loc(loc: tuple[Any, ...], data: Any) -> str:
    """Render a pydantic location as agents[2].A, swapping indices for agent names when known."""
    out = ""
    node = data
    for part in loc:
        if isinstance(part, int):
            label = str(part)
            if isinstance(node, list) and part < len(node) and isinstance(node[part], dict) and "name" in node[part]:
                label = f"{part}:{node[part]['name']}"
            out += f"[{label}]"
            node = node[part] if isinstance(node, list) and part < len(node) else None
        else:
            out += ("." if out else "") + str(part)
            node = node.get(part) if isinstance(node, dict) else None
    return out or "<root>"


def parse_spec(data: dict[str, Any], source: str = "<spec>") -> HinfSpec:
    """Validate a decoded spec dict; errors name the source and each failing field."""
    try:
        return HinfSpec.model_validate(data)
    except ValidationError as exc:
        lines = [f"{source}: {_loc(e['loc'], data)}: {e['msg']}" for e in exc.errors()]
        raise SpecError("\n".join(lines)) from None


def load_spec(path: Path | str, overrides: list[str] | tuple[str, ...] = ()) -> HinfSpec:
    """Read a .toml or .json spec file; ``overrides`` are ``dotted.key=TOML value`` strings (e.g.
    ``run.duration=10``) applied before validation."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise SpecError(f"{path}: cannot read: {exc.strerror}") from None
    try:
        if path.suffix == ".json":
            data = json.loads(raw)
        else:
            data = tomllib.loads(raw.decode())
    except (json.JSONDecodeError, tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise SpecError(f"{path}: syntax error: {exc}") from None
    if not isinstance(data, dict):
        raise SpecError(f"{path}: top level must be a table/object")
    if overrides:
        from config.loader import ScenarioError, deep_merge, parse_overrides

        try:
            deep_merge(data, parse_overrides(overrides))
        except ScenarioError as exc:
            raise SpecError(f"{path}: {exc}") from None
    return parse_spec(data, str(path))


def random_ring_spec(n_agents: int, rng: np.random.Generator, alpha: float = 0.1,
                     omega: float = 0.1) -> dict[str, Any]:
    """Spec dict of a directed ring of random heterogeneous agents (bench and tests).

    Orders 2-3, spectra in [-1, 0.2] (some mildly unstable, so cooperation matters), one output.
    """
    agents = []
    for i in range(n_agents):
        n = int(rng.integers(2, 4))
        eig = rng.uniform(-1.0, 0.2, n)
        Q, _ = np.linalg.qr(rng.normal(size=(n, n)))  # orthogonal: keeps the SDP well conditioned
        A = Q @ (np.diag(eig) + np.triu(0.5 * rng.normal(size=(n, n)), 1)) @ Q.T
        agents.append({
            "name": f"a{i}", "A": A.tolist(), "B": rng.normal(size=(n, 1)).tolist(),
            "Bt": (0.5 * rng.normal(size=(n, 1))).tolist(), "C": (rng.normal(size=(1, n)) + np.eye(1, n)).tolist(),
            "pi": 0.025,
        })
    edges = [[f"a{(i + 1) % n_agents}", f"a{i}"] for i in range(n_agents)]
    return {"name": f"ring{n_agents}", "omega": omega, "alpha": alpha, "agents": agents, "edges": edges}
