"""The linger guard (net/zenoh_transport.py): Zenoh's 10 s SO_LINGER made closing a dead link block
a router thread for 10 s (docs/faults.md); coload's sessions turn it off on their TCP sockets."""

from __future__ import annotations

import os
import socket
import stat
import struct
import sys

import pytest

from net.zenoh_transport import close_session, disable_linger_once, free_tcp_port, open_router, open_session, zenoh_config

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/fd")


def _linger(sock: socket.socket) -> tuple[int, int]:
    return struct.unpack("ii", sock.getsockopt(socket.SOL_SOCKET, socket.SO_LINGER, 8))


def _tcp_lingers() -> list[tuple[int, int]]:
    """SO_LINGER of every TCP socket of this process."""
    out = []
    for name in os.listdir("/proc/self/fd"):
        try:
            if not stat.S_ISSOCK(os.fstat(int(name)).st_mode):
                continue
            s = socket.socket(fileno=os.dup(int(name)))
        except OSError:
            continue
        with s:
            if s.type == socket.SOCK_STREAM and s.family in (socket.AF_INET, socket.AF_INET6):
                out.append(_linger(s))
    return out


def test_disable_linger_once_turns_it_off():
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 10))
        assert _linger(s) == (1, 10)
        assert disable_linger_once() >= 1
        assert _linger(s)[0] == 0
        seen: set[int] = set()
        disable_linger_once(seen)
        assert os.fstat(s.fileno()).st_ino in seen  # handled once, skipped by later scans


def test_router_and_client_links_have_no_linger():
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    router = open_router([endpoint])
    try:
        client = open_session(zenoh_config("client", connect=[endpoint]))
        try:
            lingers = _tcp_lingers()
            # the listener, the router's accepted link and the client's link at least
            assert len(lingers) >= 3
            assert all(on == 0 for on, _ in lingers), lingers
        finally:
            close_session(client)
    finally:
        close_session(router)
