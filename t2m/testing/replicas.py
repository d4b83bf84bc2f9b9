"""Replicas of the service on loopback ports that can be killed, stopped and restarted: containers of the image
(host network, each on its own T2M_PORT) or, where there is no Docker engine, `t2m serve` processes.

Both kinds run the command the image runs (`t2m serve`) on the embedded default model with one intra-op thread (a
replica per core is the scale-out unit, docs/service.md), niced so that measurements never slow other work here.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

from t2m.testing.server_process import REPO, free_port, wait_until_healthy

__all__ = ["ContainerReplica", "ProcessReplica", "Replica", "make_replicas"]

REPLICA_ENV = {"T2M_INTRA_OP_THREADS": "1", "T2M_ENGINE_WORKERS": "1", "OMP_NUM_THREADS": "1"}


class Replica(Protocol):
    port: int

    @property
    def url(self) -> str: ...
    def start(self) -> None: ...
    def wait_healthy(self, timeout_s: float = 180.0) -> None: ...
    def signal(self, signum: int) -> None: ...
    def wait_exit(self, timeout_s: float) -> int: ...
    def remove(self) -> None: ...
    def logs(self) -> str: ...


@dataclass
class ProcessReplica:
    """`python -m t2m.cli serve --host 127.0.0.1 --port P` (the code of this checkout), output in log_dir."""
    port: int
    log_dir: Path
    env: dict[str, str] = field(default_factory=dict)
    process: subprocess.Popen | None = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @property
    def log_path(self) -> Path:
        return self.log_dir / f"replica-{self.port}.log"

    def start(self) -> None:
        self.log_dir.mkdir(parents=True, exist_ok=True)
        env = {**os.environ, **REPLICA_ENV, **self.env, "PYTHONPATH": str(REPO)}
        command = [sys.executable, "-m", "t2m.cli", "serve", "--host", "127.0.0.1", "--port", str(self.port)]
        with open(self.log_path, "ab") as log:
            self.process = subprocess.Popen(command, cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT,
                                            preexec_fn=lambda: os.nice(19))

    def wait_healthy(self, timeout_s: float = 180.0) -> None:
        wait_until_healthy(self.url, timeout_s, self.process, self.log_path)

    def signal(self, signum: int) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signum)

    def wait_exit(self, timeout_s: float) -> int:
        assert self.process is not None
        return self.process.wait(timeout=timeout_s)

    def logs(self) -> str:
        return self.log_path.read_text(errors="replace") if self.log_path.exists() else ""

    def remove(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait(timeout=10)


@dataclass
class ContainerReplica:
    """`docker run --network host -e T2M_HOST=127.0.0.1 -e T2M_PORT=P IMAGE` (the image's own entrypoint)."""
    port: int
    image: str
    env: dict[str, str] = field(default_factory=dict)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @property
    def name(self) -> str:
        return f"t2m-replica-{self.port}"

    def _docker(self, *args: str, check: bool = True) -> str:
        result = subprocess.run(["docker", *args], capture_output=True, text=True, check=False)
        if check and result.returncode != 0:
            raise RuntimeError(f"docker {' '.join(args)}: {result.stderr.strip()}")
        return result.stdout.strip()

    def start(self) -> None:
        """A new container the first time; the same container again (docker start) after a kill or a stop."""
        if self._docker("container", "inspect", "-f", "{{.Id}}", self.name, check=False):
            self._docker("start", self.name)
            return
        env = {**REPLICA_ENV, **self.env, "T2M_HOST": "127.0.0.1", "T2M_PORT": str(self.port)}
        env_args = [arg for name, value in env.items() for arg in ("-e", f"{name}={value}")]
        self._docker("run", "-d", "--name", self.name, "--network", "host", *env_args, self.image)

    def wait_healthy(self, timeout_s: float = 180.0) -> None:
        deadline = time.monotonic() + timeout_s
        while self._docker("inspect", "-f", "{{.State.Running}}", self.name) != "true":
            if time.monotonic() > deadline:
                raise TimeoutError(f"{self.name} is not running: {self._docker('logs', self.name)[-2000:]}")
            time.sleep(0.2)
        wait_until_healthy(self.url, max(1.0, deadline - time.monotonic()))

    def signal(self, signum: int) -> None:
        """The signal to the container's main process, the server (docker kill -s)."""
        self._docker("kill", "-s", signal.Signals(signum).name, self.name)

    def wait_exit(self, timeout_s: float) -> int:
        result = subprocess.run(["docker", "wait", self.name], capture_output=True, text=True, timeout=timeout_s,
                                check=True)
        return int(result.stdout.strip())

    def logs(self) -> str:
        result = subprocess.run(["docker", "logs", self.name], capture_output=True, text=True, check=False)
        return result.stdout + result.stderr

    def remove(self) -> None:
        self._docker("rm", "-f", self.name, check=False)


def make_replicas(count: int, log_dir: Path, image: str | None = None,
                  env: dict[str, str] | None = None) -> list[Replica]:
    """`count` replicas on free loopback ports: containers of `image`, or processes when image is None."""
    replicas: list[Replica] = []
    ports: set[int] = set()
    while len(ports) < count:  # free_port() binds and releases: two calls may give the same port
        ports.add(free_port())
    for port in sorted(ports):
        if image:
            replicas.append(ContainerReplica(port=port, image=image, env=dict(env or {})))
        else:
            replicas.append(ProcessReplica(port=port, log_dir=log_dir, env=dict(env or {})))
    return replicas
