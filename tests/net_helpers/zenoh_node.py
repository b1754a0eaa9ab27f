"""A Zenoh node in its own OS process, for the transport tests.

``router --listen EP``: an embedded router. ``token --connect EP --key K``: a session (peer mode by
default) holding one liveliness token. Both print ``READY`` on stdout once up, then run until
signalled (SIGTERM: clean close; SIGKILL/SIGSTOP: what the tests use to fake a crash or a hang).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import zenoh  # noqa: E402

from net.zenoh_transport import run_router, zenoh_config  # noqa: E402


def _ready() -> None:
    print("READY", flush=True)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser()
    p.add_argument("role", choices=["router", "token"])
    p.add_argument("--listen", action="append", default=[])
    p.add_argument("--connect", action="append", default=[])
    p.add_argument("--key")
    p.add_argument("--mode", default="peer", choices=["peer", "client"])
    p.add_argument("--lease-ms", type=int)
    a = p.parse_args(argv)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    if a.role == "router":
        run_router(a.listen, stop=stop, lease_ms=a.lease_ms, on_ready=_ready)
        return
    conf = zenoh_config(a.mode, connect=a.connect, listen=a.listen, lease_ms=a.lease_ms)
    with zenoh.open(conf) as session:
        token = session.liveliness().declare_token(a.key)
        _ready()
        stop.wait()
        token.undeclare()


if __name__ == "__main__":
    main()
