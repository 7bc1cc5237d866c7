"""A Ray cluster of several nodes on this one machine, for tests and benchmarks: the head
node, and further nodes that may each run in their own mount namespace with an empty
tmpfs over a folder (the workspace), as a machine without the shared filesystem would.

Every process it starts it stops, by process group (never a broad ``ray stop``). Needs
root and ``unshare`` for hidden folders.
"""

from __future__ import annotations

import contextlib
import os
import shlex
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

RAY = str(Path(sys.executable).with_name("ray"))
#: for a cluster on the loopback interface only: no token, quick detection of a dead node
ENV = {"RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0", "RAY_health_check_period_ms": "500",
       "RAY_health_check_failure_threshold": "4", "RAY_health_check_initial_delay_ms": "0"}


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


class LocalCluster:
    """``ray start --head`` with ``head_cpus`` CPUs (``env``: variables its workers inherit);
    ``add_node`` starts another node."""

    def __init__(self, head_cpus: int = 1, env: dict[str, str] | None = None) -> None:
        self.address = f"127.0.0.1:{free_port()}"
        self.cpus = 0
        self.head = self._start([RAY, "start", "--head", f"--num-cpus={head_cpus}",
                                 f"--port={self.address.split(':')[1]}", "--include-dashboard=false",
                                 "--disable-usage-stats", "--block"], env)
        self.nodes: list[subprocess.Popen] = []
        self._wait_for_cpus(head_cpus)

    def _start(self, command: list[str], env: dict[str, str] | None = None) -> subprocess.Popen:
        return subprocess.Popen(command, env={**os.environ, **ENV, **(env or {})}, start_new_session=True,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def total_cpus(self) -> float:
        result = subprocess.run([RAY, "status", "--address", self.address], capture_output=True, text=True,
                                env={**os.environ, **ENV}, timeout=60)
        for line in result.stdout.splitlines():
            if line.strip().endswith(" CPU") and "/" in line:
                return float(line.split("/")[1].split()[0])
        return 0.0

    def _wait_for_cpus(self, cpus: int, timeout_s: float = 90.0) -> None:
        deadline = time.monotonic() + timeout_s
        while self.total_cpus() != self.cpus + cpus:
            if time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"the local Ray cluster did not reach {self.cpus + cpus} CPUs")
            time.sleep(0.5)
        self.cpus += cpus

    def add_node(self, cpus: int = 1, hidden: Path | None = None, env: dict[str, str] | None = None
                 ) -> subprocess.Popen:
        """Start a node; with ``hidden``, in its own mount namespace where that folder is an
        empty tmpfs (the node cannot see what the driver writes there); ``env``: variables
        its workers inherit (a node set up differently)."""
        start = " ".join(["exec", "env", *(f"{k}={shlex.quote(v)}" for k, v in (env or {}).items()), RAY, "start",
                          f"--address={self.address}", f"--num-cpus={cpus}", "--block"])
        if hidden is None:
            node = self._start(["sh", "-c", start])
        else:
            Path(hidden).mkdir(parents=True, exist_ok=True)
            script = f"mount -t tmpfs speedplus-hidden {hidden} && {start}"
            node = self._start(["unshare", "--mount", "--propagation", "private", "sh", "-c", script])
        self.nodes.append(node)
        self._wait_for_cpus(cpus)
        return node

    def kill_node(self, node: subprocess.Popen, cpus: int = 1) -> None:
        """SIGKILL a node and every process of it, as a machine that fails."""
        os.killpg(node.pid, signal.SIGKILL)
        node.wait()
        self.nodes.remove(node)
        self.cpus -= cpus

    def stop(self) -> None:
        for process in [*self.nodes, self.head]:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)
            process.wait()
        self.nodes = []

    def __enter__(self) -> LocalCluster:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()
