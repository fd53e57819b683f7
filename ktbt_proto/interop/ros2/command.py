"""``ktbt ros2``: added to the ``ktbt`` command through the ``ktbt.commands`` entry point
(spec/protocol.md section 11; docs/tutorials/ros2.md). Nothing of ROS is imported until a
command runs, so ``ktbt`` works without ROS 2, and each command says in one line what is
missing.

- ``ktbt ros2 build``: build ``ktbt_interfaces`` into this environment (cached);
- ``ktbt ros2 run [--autostart] [--ros-args ...]``: one robot's agent as a lifecycle node;
- ``ktbt ros2 lifecycle NODE TRANSITION``: a transition (configure, activate, deactivate,
  cleanup, shutdown) or ``get``, through the node's standard lifecycle_msgs services, for
  machines without the ``ros2`` command line.
"""

from __future__ import annotations

import sys
from typing import Annotated, Any

import typer

ros2 = typer.Typer(help="KT-BT on ROS 2: build the interfaces, run a robot's lifecycle node.")

TRANSITIONS = ("configure", "activate", "deactivate", "cleanup", "shutdown")


def _say(text: str) -> None:
    typer.echo(text, err=True)


def _ready() -> None:
    """rclpy and the interfaces importable, or one line and exit 1."""
    from ktbt_proto.interop.ros2 import interfaces

    try:
        import rclpy  # noqa: F401
    except ImportError:
        _say(f"error: {interfaces.not_here()}")
        raise typer.Exit(1) from None
    try:
        import ktbt_interfaces.msg  # noqa: F401
    except ImportError:
        _say("error: ktbt_interfaces is not built here: run ktbt ros2 build")
        raise typer.Exit(1) from None


@ros2.command("build")
def build_command(
    force: Annotated[bool, typer.Option(help="Build even if up to date.")] = False,
) -> None:
    """Build ros2/ktbt_interfaces into this environment from the ROS 2 wheels (skipped when
    up to date)."""
    from ktbt_proto.interop.ros2 import interfaces

    try:
        built = interfaces.build(_say, force=force)
    except interfaces.Ros2Unavailable as exc:
        _say(f"error: {exc}")
        raise typer.Exit(1) from None
    if not built:
        _say(f"{interfaces.PACKAGE} is up to date")


@ros2.command("run", context_settings={"allow_extra_args": True, "ignore_unknown_options": True})
def run_command(
    ctx: typer.Context,
    autostart: Annotated[
        bool, typer.Option(help="Configure and activate at once (no lifecycle manager).")
    ] = False,
    node_name: Annotated[str, typer.Option("--node-name", help="The node's name.")] = "ktbt",
) -> None:
    """Run one robot's KT-BT agent as a managed (lifecycle) node until Ctrl-C. ROS arguments
    follow: --ros-args -r __ns:=/robot1 --params-file robot1.yaml"""
    _ready()
    import signal
    import threading

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    from rclpy.utilities import try_shutdown

    from ktbt_proto.interop.ros2.node import KtbtNode

    extra = list(ctx.args)
    if extra and extra[0] != "--ros-args":
        _say(f"error: unexpected {extra[0]!r}: ROS arguments come after --ros-args")
        raise typer.Exit(2)
    try:
        # Our own handlers: the node is cleaned up (its summary logged, its files closed)
        # before the context goes, on Ctrl-C and on SIGTERM alike.
        rclpy.init(args=[sys.argv[0], *extra], signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:  # rclpy's own error for bad ROS arguments
        _say(f"error: --ros-args: {exc}".splitlines()[0])
        raise typer.Exit(2) from None
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    code = 0
    node: Any = None
    try:
        node = KtbtNode(node_name)
        if autostart:
            node.trigger_configure()
            if node.agent is None:
                code = 1
            else:
                node.trigger_activate()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        while code == 0 and not stop.is_set():
            executor.spin_once(timeout_sec=0.1)
    except Exception as exc:  # a parameter file of the wrong types, say: one line
        _say(f"error: {type(exc).__name__}: {exc}".splitlines()[0])
        code = 1
    finally:
        if node is not None:
            node.destroy_node()
        try_shutdown()
    raise typer.Exit(code)


@ros2.command("lifecycle")
def lifecycle_command(
    node: Annotated[str, typer.Argument(help="The node's full name: /robot1/ktbt.")],
    transition: Annotated[
        str, typer.Argument(help="configure, activate, deactivate, cleanup, shutdown, or get.")
    ],
    timeout: Annotated[float, typer.Option(help="Seconds to wait for the node.")] = 10.0,
) -> None:
    """Change a managed node's state (or print it, with get) through its lifecycle services."""
    if transition not in (*TRANSITIONS, "get"):
        _say(f"error: {transition!r}: use {', '.join(TRANSITIONS)} or get")
        raise typer.Exit(2)
    if not node.startswith("/"):
        node = "/" + node
    _ready()
    import rclpy
    from lifecycle_msgs.srv import ChangeState, GetState

    rclpy.init()
    client_node = rclpy.create_node("ktbt_lifecycle")
    code = 1
    try:
        if transition == "get":
            client = client_node.create_client(GetState, f"{node}/get_state")
            request: Any = GetState.Request()
        else:
            client = client_node.create_client(ChangeState, f"{node}/change_state")
            request = ChangeState.Request()
            request.transition.label = transition
        if not client.wait_for_service(timeout_sec=timeout):
            _say(f"error: no lifecycle node {node} found within {timeout:g} s")
        else:
            future = client.call_async(request)
            rclpy.spin_until_future_complete(client_node, future, timeout_sec=timeout)
            result = future.result()
            if result is None:
                _say(f"error: {node} did not answer within {timeout:g} s")
            elif transition == "get":
                typer.echo(result.current_state.label)
                code = 0
            elif result.success:
                typer.echo(f"{node}: {transition} done")
                code = 0
            else:
                _say(f"error: {node} refused {transition} (see its log)")
    finally:
        client_node.destroy_node()
        rclpy.shutdown()
    raise typer.Exit(code)


def register(app: typer.Typer) -> None:
    app.add_typer(ros2, name="ros2")
