"""Test hosts in network namespaces, joined by veth pairs that the test creates and removes itself.

Used to make real partitions (``ip link set ... down``) where the kernel has no netem. Every name
carries the test process id, so parallel or crashed runs do not collide; ``Hosts.close`` removes all.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import uuid
from dataclasses import dataclass, field


def _ip(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True, check=False)


def netns_available() -> str | None:
    """None when namespaces can be made here, else the reason they cannot."""
    if shutil.which("ip") is None:
        return "iproute2 'ip' not installed"
    if os.geteuid() != 0:
        return "network namespaces need root"
    probe = f"cl-probe-{uuid.uuid4().hex[:6]}"
    made = _ip("netns", "add", probe)
    if made.returncode != 0:
        return f"ip netns add not permitted: {made.stderr.strip()}"
    _ip("netns", "del", probe)
    return None


@dataclass
class Hosts:
    """A star of namespaces: ``hub`` plus leaves, each leaf joined to the hub by its own veth pair.

    Addresses 10.213.<leaf>.1 (hub side) and 10.213.<leaf>.2 (leaf side), /30 per pair; they exist
    only inside these namespaces.
    """

    leaves: int
    tag: str = field(default_factory=lambda: uuid.uuid4().hex[:6])
    created: list[str] = field(default_factory=list)

    @property
    def hub(self) -> str:
        return f"cl-{self.tag}-hub"

    def leaf(self, k: int) -> str:
        return f"cl-{self.tag}-l{k}"

    def hub_addr(self, k: int) -> str:
        return f"10.213.{k}.1"

    def leaf_addr(self, k: int) -> str:
        return f"10.213.{k}.2"

    def _veth_hub(self, k: int) -> str:
        return f"h{self.tag}{k}"

    def _run(self, *args: str) -> None:
        res = _ip(*args)
        if res.returncode != 0:
            raise RuntimeError(f"ip {' '.join(args)}: {res.stderr.strip()}")

    def open(self) -> Hosts:
        for ns in [self.hub] + [self.leaf(k) for k in range(self.leaves)]:
            self._run("netns", "add", ns)
            self.created.append(ns)
            self._run("-n", ns, "link", "set", "lo", "up")
        for k in range(self.leaves):
            a, b = self._veth_hub(k), f"l{self.tag}{k}"
            self._run("link", "add", a, "netns", self.hub, "type", "veth", "peer", "name", b, "netns", self.leaf(k))
            self._run("-n", self.hub, "addr", "add", f"{self.hub_addr(k)}/30", "dev", a)
            self._run("-n", self.leaf(k), "addr", "add", f"{self.leaf_addr(k)}/30", "dev", b)
            self._run("-n", self.hub, "link", "set", a, "up")
            self._run("-n", self.leaf(k), "link", "set", b, "up")
        return self

    def cut(self, k: int) -> None:
        """A real partition: the hub's end of leaf k's link goes down."""
        self._run("-n", self.hub, "link", "set", self._veth_hub(k), "down")

    def heal(self, k: int) -> None:
        self._run("-n", self.hub, "link", "set", self._veth_hub(k), "up")

    def argv(self, ns: str, argv: list[str]) -> list[str]:
        return ["ip", "netns", "exec", ns, *argv]

    def close(self) -> None:
        for ns in reversed(self.created):
            _ip("netns", "del", ns)  # removes its veth ends too
        self.created.clear()

    def __enter__(self) -> Hosts:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()
