"""Real zenoh peers on loopback for the tests: free ports, explicit endpoints, no multicast,
processes started fresh (never forked after a session exists) and always stopped."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

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
    *args: str, ready: str | None = None, timeout: float = 30, env: dict[str, str] | None = None
) -> Iterator[subprocess.Popen[str]]:
    """Start ``python -m ktbt_proto ARGS`` (with ``env`` added to the environment); wait for
    ``ready`` on its stdout; always stop it."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "ktbt_proto", *args],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})},
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
        end(proc)
        if proc.stdout is not None:
            proc.stdout.close()


def end(proc: subprocess.Popen[str]) -> None:
    """End a process a test started, by its pid: SIGTERM, then SIGKILL if it does not stop."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=15)


def make_tls(folder: Path) -> dict[str, Path]:
    """A throw-away CA and a certificate for localhost signed by it (PEM files in ``folder``)."""
    import datetime

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    def name(cn: str) -> x509.Name:
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])

    now = datetime.datetime.now(datetime.UTC)
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca = (
        x509.CertificateBuilder()
        .subject_name(name("ktbt test CA"))
        .issuer_name(name("ktbt test CA"))
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=1))
        .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
        .sign(ca_key, hashes.SHA256())
    )
    key = ec.generate_private_key(ec.SECP256R1())
    cert = (
        x509.CertificateBuilder()
        .subject_name(name("localhost"))
        .issuer_name(ca.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=1))
        .add_extension(x509.SubjectAlternativeName([x509.DNSName("localhost")]), critical=False)
        .sign(ca_key, hashes.SHA256())
    )
    files = {"ca": folder / "ca.pem", "cert": folder / "server.pem", "key": folder / "server.key"}
    files["ca"].write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    files["cert"].write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    files["key"].write_bytes(
        key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        )
    )
    return files


def ktbt_run(*args: str, timeout: float = 90) -> subprocess.CompletedProcess[str]:
    """Run ``python -m ktbt_proto ARGS`` to completion."""
    return subprocess.run(
        [sys.executable, "-m", "ktbt_proto", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def serving(port: int, *extra: str, name: str = "teacher") -> Any:
    """A ``ktbt peer serve`` of the example colour skills on ``port``."""
    knowledge = ROOT / "examples" / "knowledge" / "colours.sbt"
    return ktbt_process(
        "peer", "serve", "--id", name, "--knowledge", str(knowledge),
        "--listen", endpoint(port), *extra, ready="serving",
    )  # fmt: skip


def settings(port: int, *connect: int) -> Any:
    """Zenoh settings listening on ``port`` of loopback and connecting to ``connect``."""
    from ktbt_proto.transport.zenoh import ZenohSettings

    return ZenohSettings(listen=[endpoint(port)], connect=[endpoint(p) for p in connect])


def wait_until(done: Callable[[], bool], seconds: float = 15) -> bool:
    deadline = time.monotonic() + seconds
    while not done():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


def see(transport: Any, *names: str) -> None:
    """Wait until ``transport`` sees the peers ``names``."""
    from ktbt_proto.transport.zenoh import peers

    assert wait_until(lambda: set(names) <= set(peers(transport, 0.3)), 15)


def reached(transport: Any, name: str, seconds: float = 15) -> None:
    """Wait until peer ``name`` has answered ``transport`` (its catalog, on ``name``'s own key).

    A peer's messages on a link arrive in the order it sent them, so the answer is a round trip
    that orders declarations both ways: what ``transport`` declared before asking (a
    subscription, say) has reached ``name``, and what ``name`` declared before answering has
    reached ``transport``. No fixed sleep can promise either."""

    def answered() -> bool:
        replies = transport.session.get(f"ktbt/v1/catalog/{name}", timeout=1)
        return any(r.ok is not None for r in replies)

    assert wait_until(answered, seconds), f"{name} never answered {transport.name}"


class Output:
    """A process's output, read line by line in a thread of its own, so a test can wait for a
    line while the process runs."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.lines: list[str] = []
        self._proc = proc
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        assert self._proc.stdout is not None
        for line in self._proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def text(self) -> str:
        return "\n".join(self.lines)

    def wait_for(self, *needles: str, seconds: float = 30) -> None:
        assert wait_until(lambda: all(n in self.text() for n in needles), seconds), (
            f"never printed {needles}:\n{self.text()[-3000:]}"
        )

    def join(self) -> None:
        self._thread.join(timeout=15)
