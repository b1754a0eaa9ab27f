"""A live view: a run's load pose and estimates, from Zenoh, streamed to Foxglove's WebSocket server.

:class:`LiveScene` (pure) turns the simulator's pose notices (``coload/{run}/sim/pose``) and the
agents' estimates (``coload/{run}/agent/*/estimate``) into the messages of :mod:`coload.viz.scene`,
the same that ``coload export --mcap`` writes; :func:`watch` subscribes and logs them to Foxglove
channels until the run's ``done`` notice or a stop. Needs the ``viz`` extra. docs/viewers.md.
"""

from __future__ import annotations

import asyncio
import logging
import math
import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from coload.viz.scene import SCHEMAS, Message, channels, estimate_topic, frame, t_ns
from net.messages import Control, Estimate, LoadPose

log = logging.getLogger(__name__)


class LiveScene:
    """The latest estimate of every agent, and the scene each pose notice makes of them."""

    def __init__(self, n: int, dt: float, outline_body: np.ndarray) -> None:
        self.n, self.dt, self.outline = n, dt, outline_body
        self.latest: dict[int, dict[str, float]] = {}

    def on_estimate(self, est: Estimate) -> list[Message]:
        if not 0 <= est.agent < self.n:
            return []
        t = est.tick * self.dt
        row: dict[str, Any] = {"t": t, "agent": est.agent}
        row.update({k: (v if math.isfinite(v) else None) for k, v in est.values.items()})
        self.latest[est.agent] = {k: float(v) for k, v in est.values.items()}
        return [Message(t_ns(t), estimate_topic(est.agent), row)]

    def on_pose(self, pose: LoadPose) -> list[Message]:
        z = np.asarray(pose.z, dtype=float).reshape(-1, 2)
        if len(z) != self.n:
            return []
        return frame(t_ns(pose.tick * self.dt), (pose.x, pose.y, pose.angle), (pose.pg_x, pose.pg_y), z,
                     self.outline, self.latest, self.n)


class FoxgloveSink:
    """Foxglove's WebSocket server with one JSON channel per topic of :func:`coload.viz.scene.channels`."""

    def __init__(self, n: int, host: str, port: int) -> None:
        import foxglove

        self.server = foxglove.start_server(name="coload", host=host, port=port)
        self.channels = {topic: foxglove.Channel(topic, schema=SCHEMAS[name])
                         for topic, name in channels(n).items()}

    @property
    def port(self) -> int:
        return self.server.port

    def log(self, msgs: list[Message]) -> None:
        for m in msgs:
            self.channels[m.topic].log(m.body, log_time=m.t_ns)

    def close(self) -> None:
        self.server.stop()


async def watch(transport: Any, run: str, scene: LiveScene, sink: Callable[[list[Message]], None],
                stop: asyncio.Event, subscribed: Callable[[], None] = lambda: None) -> dict[str, int]:
    """Forward a run to ``sink`` until its ``done`` notice or ``stop``; return messages per kind."""
    from net import keys
    from net.schema import DecodeError, decode

    counts = {"pose": 0, "estimate": 0, "dropped": 0}

    def on_pose(key: str, payload: bytes) -> None:
        try:
            sink(scene.on_pose(decode(payload, LoadPose)))
            counts["pose"] += 1
        except DecodeError:
            counts["dropped"] += 1

    def on_estimate(key: str, payload: bytes) -> None:
        try:
            sink(scene.on_estimate(decode(payload, Estimate)))
            counts["estimate"] += 1
        except DecodeError:
            counts["dropped"] += 1

    def on_control(key: str, payload: bytes) -> None:
        try:
            if decode(payload, Control).kind == "done":
                stop.set()
        except DecodeError:
            counts["dropped"] += 1

    subs = [transport.subscribe(keys.sim_pose(run), on_pose),
            transport.subscribe(keys.agent_all(run, "estimate"), on_estimate),
            transport.subscribe(keys.sim_control(run), on_control)]
    subscribed()
    try:
        await stop.wait()
    finally:
        for s in subs:
            s.close()
    return counts


class ViewThread:
    """``coload run --view``: :func:`watch` on a thread of its own, beside the run's orchestration."""

    def __init__(self, conf: Any, run: str, scene: LiveScene, sink: FoxgloveSink) -> None:
        self._conf, self._run, self._scene, self._sink = conf, run, scene, sink
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._ready = threading.Event()
        self.counts: dict[str, int] = {}
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._main, name="coload-view", daemon=True)

    def start(self, timeout: float = 10.0) -> None:
        self._thread.start()
        self._ready.wait(timeout)

    def _main(self) -> None:
        from net.zenoh_transport import ZenohTransport

        async def go() -> None:
            self._loop = asyncio.get_running_loop()
            self._stop = asyncio.Event()
            transport = ZenohTransport(self._conf, self._loop)
            try:
                self.counts = await watch(transport, self._run, self._scene, self._sink.log, self._stop,
                                          self._ready.set)
            finally:
                transport.close()

        try:
            asyncio.run(go())
        except BaseException as exc:  # noqa: BLE001  reported by stop(); the run itself goes on
            self.error = exc
            self._ready.set()

    def stop(self, timeout: float = 5.0) -> None:
        if self._thread.is_alive() and self._loop is not None and self._stop is not None:
            try:
                self._loop.call_soon_threadsafe(self._stop.set)
            except RuntimeError:  # the run's done notice ended it meanwhile
                pass
        self._thread.join(timeout)
