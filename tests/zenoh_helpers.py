"""Real zenoh peers on loopback for the tests: free ports, explicit endpoints, no multicast,
processes started fresh (never forked after a session exists) and always stopped."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def endpoint(port: int) -> str:
    return f"tcp/127.0.0.1:{port}"


@contextmanager
def ktbt_process(
    *args: str, ready: str | None = None, timeout: float = 30
) -> Iterator[subprocess.Popen[str]]:
    """Start ``python -m ktbt_proto ARGS``; wait for ``ready`` on its stdout; always stop it."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "ktbt_proto", *args],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        if ready is not None:
            deadline = time.monotonic() + timeout
            assert proc.stdout is not None
            while time.monotonic() < deadline:
                line = proc.stdout.readline()
                if ready in line:
                    break
                if not line and proc.poll() is not None:
                    raise AssertionError(f"{args[:2]} exited with {proc.returncode}")
            else:
                raise AssertionError(f"{args[:2]} never printed {ready!r}")
        yield proc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=15)
        if proc.stdout is not None:
            proc.stdout.close()
