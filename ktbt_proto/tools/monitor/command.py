"""``ktbt monitor``: added to the ``ktbt`` command through the ``ktbt.commands`` entry point.
Nothing of the web stack is imported until the command runs, so ``ktbt`` works without the
``monitor`` extra and the command says in one line how to get it."""

from __future__ import annotations

import contextlib
import errno
import ipaddress
import os
import socket
from pathlib import Path
from typing import Annotated, Any

import typer

from ktbt_proto.tools.cli.options import (
    Connect,
    JoinMode,
    TrustFile,
    ZenohConfig,
    address,
    example,
    refuse,
    zenoh_settings,
)

INSTALL = "ktbt monitor needs the monitor extra: pip install 'ktbt[monitor]'"
LOOPBACK_NAMES = ["127.0.0.1", "localhost", "::1", "[::1]"]


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def allowed_hosts(host: str, allow: list[str]) -> list[str]:
    """The Host headers a page may send: the loopback names when bound to loopback, else the
    bound address itself, and every ``--allow-host`` (a page reached by another name, as by
    DNS rebinding, is refused)."""
    bound = LOOPBACK_NAMES if _is_loopback(host) else [host, f"[{host}]" if ":" in host else host]
    return [*dict.fromkeys([*bound, *allow])]


def monitor_command(
    connect: Connect = None,
    http: Annotated[
        str,
        typer.Option(
            "--http",
            metavar="HOST:PORT",
            help="Where to serve the page, HOST:PORT; a host other than loopback is reachable "
            "from other machines (pages must then name it or an --allow-host).",
        ),
    ] = "127.0.0.1:8470",
    allow_host: Annotated[
        list[str] | None,
        typer.Option(
            "--allow-host", metavar="HOST", help="Another Host name a page may use (repeatable)."
        ),
    ] = None,
    config: ZenohConfig = None,
    mode: JoinMode = "peer",
    uds: Annotated[
        Path | None,
        typer.Option(
            "--uds",
            metavar="PATH",
            help="Also serve on this unix socket, for tools on this machine (as in a network "
            "namespace of their own) that cannot reach the --http address.",
        ),
    ] = None,
    trust: TrustFile = None,
    ros2: Annotated[
        bool,
        typer.Option(
            "--ros2",
            help="Also show the ROS 2 robots (ktbt ros2 run) found through the ROS graph "
            "(ROS_DOMAIN_ID as for any ROS node).",
        ),
    ] = False,
) -> None:
    """Serve a live view of the fleet in the browser.

    It shows who is present, who knows what, each transfer and refusal as it happens
    (spec/protocol.md section 10). With --trust, the peers named there must sign their
    events; others' first key is pinned. With --ros2, ROS 2 robots show beside zenoh
    peers, and --connect may be left out."""
    try:
        import uvicorn

        from ktbt_proto.tools.monitor.app import create_app
        from ktbt_proto.tools.monitor.listen import Listener
        from ktbt_proto.tools.monitor.state import FleetState
    except ImportError:
        typer.echo(INSTALL, err=True)
        raise typer.Exit(2) from None
    from ktbt_proto.exchange.signing import KeyFileError
    from ktbt_proto.exchange.trust import TrustStore
    from ktbt_proto.tools.peer import until_signalled

    if not connect and not ros2:
        raise refuse("--connect: required: the fleet to listen to (--connect ENDPOINT, or --ros2)")
    settings = zenoh_settings(None, connect, config, False, mode)
    if ros2:
        from ktbt_proto.tools.ros2.interfaces import not_here

        try:
            import rclpy  # noqa: F401
        except ImportError:
            raise refuse(f"--ros2: {not_here()}") from None
        try:
            import ktbt_interfaces.msg  # noqa: F401
        except ImportError:
            raise refuse("--ros2: ktbt_interfaces is not built here: run ktbt ros2 build") from None
    try:
        store = TrustStore.load(trust) if trust is not None else None
    except KeyFileError as exc:
        raise refuse(str(exc)) from None
    host, port = address(http, "--http")
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise refuse(f"cannot serve on {http}: {exc.strerror or exc}") from None
    port = sock.getsockname()[1]
    sockets = [sock]
    bound: tuple[int, int] | None = None
    if uds is not None:
        try:
            unix, bound = _unix_socket(uds)
        except OSError as exc:
            sock.close()
            raise refuse(f"cannot serve on {uds}: {exc.strerror or exc}") from None
        sockets.append(unix)
    fleet = FleetState(store)
    try:
        # Without --connect (a ROS 2 fleet alone) the zenoh session joins no one: it only
        # checks what the ROS listener hears.
        listener = Listener(fleet, settings)
    except Exception as exc:  # zenoh's own error: a bad endpoint or config
        for s in sockets:
            s.close()
        raise refuse(f"cannot join the fleet at {', '.join(connect or [])}: {exc}") from None
    ros: Any = None
    if ros2:
        from ktbt_proto.tools.monitor.ros2 import RosListener

        ros = RosListener(fleet, listener.hear)

    def tree(name: str) -> str | None:
        shown_tree = ros.tree(name) if ros is not None else None
        return shown_tree if shown_tree is not None else listener.tree(name)

    loopback = _is_loopback(host)
    shown = f"[{host}]" if family == socket.AF_INET6 else host
    # An open page's stream ends once the server is stopping; give connections a second.
    app = create_app(
        fleet, allowed_hosts(host, allow_host or []), tree, stopping=lambda: server.should_exit
    )
    server = uvicorn.Server(
        uvicorn.Config(app, log_level="warning", lifespan="off", timeout_graceful_shutdown=1)
    )
    if loopback:
        typer.echo(f"monitor: http://{shown}:{port}/ (localhost only; --http HOST:PORT to change)")
    else:
        typer.echo(f"monitor: http://{shown}:{port}/ (reachable from other machines: not loopback)")
    if uds is not None:
        typer.echo(f"  and on the unix socket {uds}")
    heard = [f"the fleet at {', '.join(connect)}"] if connect else []
    heard += ["the ROS 2 graph"] if ros2 else []
    typer.echo(f"  listening to {' and '.join(heard)}; Ctrl-C to stop")
    try:
        # uvicorn handles SIGINT and SIGTERM while it runs, then raises the signal again once
        # stopped: caught here, so the listener's session is closed below.
        with until_signalled():
            server.run(sockets=sockets)
    finally:
        if ros is not None:
            ros.close()
        listener.close()
        for s in sockets:
            s.close()
        if uds is not None and bound is not None:
            with contextlib.suppress(OSError):  # ours still: not one a later monitor bound
                if (uds.stat().st_dev, uds.stat().st_ino) == bound:
                    uds.unlink()


def _unix_socket(path: Path) -> tuple[socket.socket, tuple[int, int]]:
    """A unix socket bound at ``path``, readable by its owner only, and its file's identity.
    A socket left there by a monitor that died is replaced; one that still answers, or a
    file that is not a socket, is refused (``OSError``)."""
    if path.is_socket():
        probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            probe.connect(str(path))
        except ConnectionRefusedError:
            path.unlink()  # nobody listens: left by a monitor that died
        else:
            raise OSError(errno.EADDRINUSE, "another process serves on it")
        finally:
            probe.close()
    unix = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        unix.bind(str(path))
        unix.listen()  # at once: a monitor starting beside us must see this one taken
        os.chmod(path, 0o600)
        stat = path.stat()
    except OSError:
        unix.close()
        raise
    return unix, (stat.st_dev, stat.st_ino)


def register(app: typer.Typer) -> None:
    """Entry point of ``ktbt.commands``: add ``monitor`` to the ``ktbt`` app."""
    app.command("monitor", epilog=example("ktbt monitor --connect tcp/127.0.0.1:7447"))(
        monitor_command
    )
