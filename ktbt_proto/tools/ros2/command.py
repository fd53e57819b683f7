"""``ktbt ros2``: added to the ``ktbt`` command through the ``ktbt.commands`` entry point
(spec/protocol.md section 11; docs/tutorials/ros2.md). Nothing of ROS is imported until a
command runs, so ``ktbt`` works without ROS 2, and each command says in one line what is
missing.

- ``ktbt ros2 build``: build ``ktbt_interfaces`` into this environment (cached);
- ``ktbt ros2 run [--autostart] [--ros-args ...]``: one robot's agent as a lifecycle node;
- ``ktbt ros2 lifecycle NODE TRANSITION``: a transition (configure, activate, deactivate,
  cleanup, shutdown) or ``get``, through the node's standard lifecycle_msgs services;
- ``ktbt ros2 list NODE [--until SEQUENCE]`` and ``ktbt ros2 forget NODE SEQUENCE``: what a
  robot knows, and forgetting an item, through its services;
- ``ktbt ros2 bridge --connect ENDPOINT``: relay knowledge between a zenoh fleet and a ROS 2
  fleet, both ways (``ktbt_proto.tools.ros2.bridge``);

the last three for machines without the ``ros2`` command line.
"""

from __future__ import annotations

import contextlib
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Annotated, Any, Literal

import typer

from ktbt_proto.exchange.trust import Policy
from ktbt_proto.tools.cli.options import (
    Connect,
    JoinMode,
    Listen,
    Timeout,
    TrustFile,
    ZenohConfig,
    example,
    refuse,
    zenoh_settings,
)

ros2 = typer.Typer(
    help="KT-BT on ROS 2: build the interfaces, run a robot's lifecycle node.",
    no_args_is_help=True,
)

TRANSITIONS = ("configure", "activate", "deactivate", "cleanup", "shutdown")


def _say(text: str) -> None:
    typer.echo(text, err=True)


def _ready() -> None:
    """rclpy and the interfaces importable, or one line and exit 1."""
    from ktbt_proto.tools.ros2 import interfaces

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


Executor = Literal["single", "events"]
"""The executor ``ktbt ros2 run`` spins its node with (spec/protocol.md section 11)."""


@ros2.command("build", epilog=example("ktbt ros2 build"))
def build_command(
    force: Annotated[bool, typer.Option("--force", help="Build even if up to date.")] = False,
) -> None:
    """Build the interfaces into this environment (cached).

    ros2/ktbt_interfaces and ros2/ktbt_example_interfaces, from the ROS 2 wheels; each skipped
    while up to date."""
    from ktbt_proto.tools.ros2 import interfaces

    try:
        built = interfaces.build(_say, force=force)
    except interfaces.Ros2Unavailable as exc:
        _say(f"error: {exc}")
        raise typer.Exit(1) from None
    if not built:
        _say(f"{', '.join(interfaces.PACKAGES)}: up to date")


def _ros_args(ctx: typer.Context) -> list[str]:
    """What follows ``--ros-args`` (rclpy's to read); anything else the command line does not
    know is one line naming it, exit 2."""
    extra = list(ctx.args)
    if extra and extra[0] != "--ros-args":
        if extra[0].startswith("-"):
            raise refuse(f"{extra[0]}: no such option")
        raise refuse(f"{extra[0]!r}: unexpected; ROS arguments come after --ros-args")
    return extra


@ros2.command(
    "run",
    context_settings={"allow_extra_args": True, "ignore_unknown_options": True},
    epilog=example("ktbt ros2 run --autostart --ros-args -r __ns:=/robot1 --params-file r1.yaml"),
)
def run_command(
    ctx: typer.Context,
    autostart: Annotated[
        bool,
        typer.Option("--autostart", help="Configure and activate at once (no lifecycle manager)."),
    ] = False,
    node_name: Annotated[
        str, typer.Option("--node-name", metavar="NAME", help="The node's name.")
    ] = "ktbt",
    executor_kind: Annotated[
        Executor,
        typer.Option(
            "--executor",
            help="events: rclpy's events executor (less than half the CPU when idle, "
            "transfers as fast); single: its SingleThreadedExecutor, rclpy.spin's.",
        ),
    ] = "events",
) -> None:
    """Run one robot's agent as a lifecycle node.

    Until Ctrl-C; ROS arguments (a namespace, a parameter file) follow --ros-args."""
    _ready()
    import signal
    import threading

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.experimental.events_executor import EventsExecutor
    from rclpy.signals import SignalHandlerOptions
    from rclpy.utilities import try_shutdown

    from ktbt_proto.tools.ros2.node import KtbtNode

    extra = _ros_args(ctx)
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
        executor = EventsExecutor() if executor_kind == "events" else SingleThreadedExecutor()
        executor.add_node(node)
        while code == 0 and not stop.is_set() and not node.finalized:
            executor.spin_once(timeout_sec=0.1)
    except Exception as exc:  # a parameter file of the wrong types, say: one line
        _say(f"error: {type(exc).__name__}: {exc}".splitlines()[0])
        code = 1
    finally:
        if node is not None:
            if not node.finalized:  # Ctrl-C or SIGTERM: through the shutdown transition
                with contextlib.suppress(Exception):
                    node.trigger_shutdown()
            node.destroy_node()
        try_shutdown()
    raise typer.Exit(code)


def _full(node: str) -> str:
    return node if node.startswith("/") else "/" + node


class _NoAnswer(Exception):
    """A node's service could not be reached or did not answer; the message says which."""


@contextmanager
def _client_node() -> Iterator[Any]:
    """A short-lived node of this command's own, in a context of its own."""
    _ready()
    import rclpy
    from rclpy.utilities import try_shutdown

    rclpy.init()
    node = rclpy.create_node("ktbt_cli")
    try:
        yield node
    finally:
        node.destroy_node()
        try_shutdown()


def _call(client_node: Any, srv_type: Any, service: str, request: Any, timeout: float) -> Any:
    """``service``'s answer to ``request``, waiting for the service at most ``timeout`` s and
    as long again for the answer; raises :class:`_NoAnswer` with one line."""
    import rclpy

    client = client_node.create_client(srv_type, service)
    try:
        if not client.wait_for_service(timeout_sec=timeout):
            raise _NoAnswer(f"no service {service} found within {timeout:g} s")
        future = client.call_async(request)
        rclpy.spin_until_future_complete(client_node, future, timeout_sec=timeout)
        result = future.result()
        if result is None:
            raise _NoAnswer(f"{service} did not answer within {timeout:g} s")
        return result
    finally:
        client_node.destroy_client(client)


REACHES = {
    "configure": "inactive",
    "activate": "active",
    "deactivate": "inactive",
    "cleanup": "unconfigured",
    "shutdown": "finalized",
}
"""The primary state each transition ends in (lifecycle_msgs' state machine)."""

SLICE = 0.5
"""Seconds a lifecycle command waits for a reply before it reads the node's state."""


def _state(client_node: Any, getter: Any, timeout: float) -> str | None:
    """The node's state label through ``getter`` (a GetState client), or None when its
    service has left the graph (the node is gone) or did not answer within ``timeout``."""
    import rclpy
    from lifecycle_msgs.srv import GetState

    if not getter.service_is_ready():
        return None
    future = getter.call_async(GetState.Request())
    rclpy.spin_until_future_complete(client_node, future, timeout_sec=timeout)
    result = future.result()
    return None if result is None else str(result.current_state.label)


def _transition(client_node: Any, node: str, transition: str, timeout: float) -> bool:
    """Whether ``node`` took ``transition`` (its reply's success), within ``timeout``.

    A reply can be lost: a server may send it before its reply writer has matched this
    new client, and a node that shuts down ends before its reply is delivered. So while
    the reply is late the command reads the node's state (a second service, matched by
    then): the transition's end state, reached from the state read before the request,
    counts as done (a node already there, or whose state was not read, must answer), and
    after ``shutdown`` so does the node leaving the graph (spec/protocol.md section 11)."""
    import rclpy
    from lifecycle_msgs.srv import ChangeState, GetState

    changer = client_node.create_client(ChangeState, f"{node}/change_state")
    getter = client_node.create_client(GetState, f"{node}/get_state")
    try:
        for client, name in ((changer, "change_state"), (getter, "get_state")):
            if not client.wait_for_service(timeout_sec=timeout):
                raise _NoAnswer(f"no service {node}/{name} found within {timeout:g} s")
        before = _state(client_node, getter, timeout)
        request = ChangeState.Request()
        request.transition.label = transition
        future = changer.call_async(request)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            rclpy.spin_until_future_complete(client_node, future, timeout_sec=SLICE)
            if future.done() and future.result() is not None:
                return bool(future.result().success)
            now = _state(client_node, getter, SLICE)
            if before is not None and now == REACHES[transition] != before:
                return True
            if now is None and transition == "shutdown" and not getter.service_is_ready():
                return True
        raise _NoAnswer(f"{node}/change_state did not answer within {timeout:g} s")
    finally:
        client_node.destroy_client(changer)
        client_node.destroy_client(getter)


@ros2.command("lifecycle", epilog=example("ktbt ros2 lifecycle /robot1/ktbt activate"))
def lifecycle_command(
    node: Annotated[str, typer.Argument(help="The node's full name: /robot1/ktbt.")],
    transition: Annotated[
        str, typer.Argument(help="configure, activate, deactivate, cleanup, shutdown, or get.")
    ],
    timeout: Timeout = 10.0,
) -> None:
    """Change a lifecycle node's state, or print it.

    Through the node's standard lifecycle_msgs services."""
    if transition not in (*TRANSITIONS, "get"):
        _say(f"error: {transition!r}: use {', '.join(TRANSITIONS)} or get")
        raise typer.Exit(2)
    node = _full(node)
    with _client_node() as client_node:
        from lifecycle_msgs.srv import GetState

        try:
            if transition == "get":
                got = _call(client_node, GetState, f"{node}/get_state", GetState.Request(), timeout)
                typer.echo(got.current_state.label)
                return
            took = _transition(client_node, node, transition, timeout)
        except _NoAnswer as exc:
            _say(f"error: {exc}")
            raise typer.Exit(1) from None
    if not took:
        _say(f"error: {node} refused {transition} (see its log)")
        raise typer.Exit(1)
    typer.echo(f"{node}: {transition} done")


def _shown(key: str) -> str:
    """A sequence key as people type it; one that does not parse is shown quoted."""
    from ktbt_proto.errors import StringBTError
    from ktbt_proto.items import show_sequence

    try:
        return show_sequence(key)
    except StringBTError:
        return repr(key)


def _key(option: str, text: str) -> str:
    """A sequence as typed, in wire form; a mistake is one line and exit 2."""
    from ktbt_proto.errors import StringBTError
    from ktbt_proto.items import read_sequence, sequence_key

    try:
        return sequence_key(read_sequence(text))
    except StringBTError as err:
        _say(f"error: {option} {text!r}: {err.code} {err.message}")
        raise typer.Exit(2) from None


@ros2.command("list", epilog=example("ktbt ros2 list /robot1/ktbt --until 'TargetSeen(colour=2)'"))
def list_command(
    node: Annotated[str, typer.Argument(help="The node's full name: /robot1/ktbt.")],
    until: Annotated[
        str | None,
        typer.Option(
            "--until", metavar="SEQUENCE", help="Wait (up to --timeout) until it knows this."
        ),
    ] = None,
    timeout: Timeout = 10.0,
) -> None:
    """What a robot knows.

    Each item with its author and teacher, from the node's ~/list_knowledge service."""
    wanted = _key("--until", until) if until is not None else None
    node = _full(node)
    with _client_node() as client_node:
        from ktbt_interfaces.srv import ListKnowledge

        deadline = time.monotonic() + timeout
        while True:
            try:
                items = _call(
                    client_node,
                    ListKnowledge,
                    f"{node}/list_knowledge",
                    ListKnowledge.Request(),
                    max(0.1, deadline - time.monotonic()),
                ).items
            except _NoAnswer as exc:
                _say(f"error: {exc}")
                raise typer.Exit(1) from None
            if wanted is None or any(item.sequence == wanted for item in items):
                break
            if time.monotonic() >= deadline:
                _say(f"error: {node} did not know {_shown(wanted)} within {timeout:g} s")
                raise typer.Exit(1)
            time.sleep(0.1)  # polling the robot's service, at most ten times a second
    typer.echo(f"{node}: {len(items)} skill{'s' * (len(items) != 1)}")
    for item in items:
        origin = [
            f"{name} {value}"
            for name, value in (("author", item.author), ("teacher", item.teacher))
            if value
        ]
        typer.echo(f"  {_shown(item.sequence)}" + (f"  ({', '.join(origin)})" if origin else ""))


@ros2.command("forget", epilog=example("ktbt ros2 forget /robot1/ktbt 'TargetSeen(colour=2)'"))
def forget_command(
    node: Annotated[str, typer.Argument(help="The node's full name: /robot1/ktbt.")],
    sequence: Annotated[str, typer.Argument(help="The item's sequence: 'TargetSeen(colour=2)'.")],
    timeout: Timeout = 10.0,
) -> None:
    """Make a robot forget a learned item.

    Through the node's ~/forget service; innate knowledge is never forgotten."""
    key = _key("SEQUENCE", sequence)
    node = _full(node)
    with _client_node() as client_node:
        from ktbt_interfaces.srv import Forget

        try:
            done = _call(
                client_node, Forget, f"{node}/forget", Forget.Request(sequence=key), timeout
            )
        except _NoAnswer as exc:
            _say(f"error: {exc}")
            raise typer.Exit(1) from None
    if not done.success:
        _say(f"error: {node}: {done.message}")
        raise typer.Exit(1)
    typer.echo(f"{node}: forgot {_shown(key)}")


def _topic(option: str, value: str) -> str:
    """A fleet topic given on the command line: absolute, or one line and exit 2."""
    if not value.startswith("/") or not value.strip("/"):
        raise refuse(f"{option}: {value!r}: use an absolute topic name, as /ktbt/queries")
    return value


@ros2.command(
    "bridge",
    context_settings={"allow_extra_args": True, "ignore_unknown_options": True},
    epilog=example("ktbt ros2 bridge --connect tcp/127.0.0.1:7447"),
)
def bridge_command(
    ctx: typer.Context,
    connect: Connect = None,
    listen: Listen = None,
    config: ZenohConfig = None,
    mode: JoinMode = "peer",
    node_name: Annotated[
        str, typer.Option("--node-name", metavar="NAME", help="The bridge's ROS node name.")
    ] = "ktbt_bridge",
    queries_topic: Annotated[
        str, typer.Option("--queries-topic", metavar="TOPIC", help="The ROS fleet's query topic.")
    ] = "/ktbt/queries",
    answers_topic: Annotated[
        str,
        typer.Option("--answers-topic", metavar="TOPIC", help="The ROS fleet's answer topic."),
    ] = "/ktbt/answers",
    errors_topic: Annotated[
        str, typer.Option("--errors-topic", metavar="TOPIC", help="The ROS fleet's error topic.")
    ] = "/ktbt/errors",
    query_timeout: Annotated[
        float,
        typer.Option(
            "--query-timeout",
            metavar="SECONDS",
            help="How long a relayed query waits for answers, (0, 60].",
        ),
    ] = 2.0,
    max_robots: Annotated[
        int,
        typer.Option("--max-robots", metavar="N", help="Robots bridged each way at most, 1-1024."),
    ] = 64,
    max_per_source: Annotated[
        int,
        typer.Option(
            "--max-per-source",
            metavar="N",
            help="ROS names one process may have mirrored (unproven), 1-1024.",
        ),
    ] = 16,
    policy: Annotated[
        Policy,
        typer.Option(
            "--policy",
            help="Whose names cross to zenoh: any, or trusted (proven by a key in --trust).",
        ),
    ] = Policy.ANY,
    trust: TrustFile = None,
) -> None:
    """Relay knowledge between a zenoh fleet and a ROS 2 fleet.

    Queries cross to the other side and answers come back to the asker, signatures intact;
    each side's robots are present on the other (spec/protocol.md section 11, "Bridge").
    Until Ctrl-C; ROS arguments follow --ros-args."""
    extra = _ros_args(ctx)
    if not connect and not listen:
        raise refuse("--connect: required: the zenoh fleet to bridge (--connect ENDPOINT)")
    settings = zenoh_settings(listen, connect, config, False, mode)
    topics_given = [
        _topic("--queries-topic", queries_topic),
        _topic("--answers-topic", answers_topic),
        _topic("--errors-topic", errors_topic),
    ]
    if len(set(topics_given)) != 3:
        raise refuse("--queries-topic: the three topics must differ")
    if not 0 < query_timeout <= 60:
        raise refuse(f"--query-timeout: {query_timeout:g}: use (0, 60] seconds")
    if not 1 <= max_robots <= 1024:
        raise refuse(f"--max-robots: {max_robots}: use 1 to 1024")
    if not 1 <= max_per_source <= 1024:
        raise refuse(f"--max-per-source: {max_per_source}: use 1 to 1024")
    if policy is Policy.SIGNED:
        raise refuse("--policy: signed: a bridge takes any, or trusted with --trust FILE")
    if policy is Policy.TRUSTED and trust is None:
        raise refuse("--policy: trusted needs --trust FILE")
    from ktbt_proto.exchange.signing import KeyFileError
    from ktbt_proto.exchange.trust import TrustStore

    try:
        store = TrustStore.load(trust) if trust is not None else None
    except (KeyFileError, OSError) as exc:
        raise refuse(f"--trust: {exc}") from None
    import re

    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]{0,54}", node_name):
        raise refuse(f"--node-name: {node_name!r}: use letters, digits and '_' (a ROS node name)")
    _ready()

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    from rclpy.utilities import try_shutdown

    from ktbt_proto.interop.ros2 import logs
    from ktbt_proto.tools.peer import until_signalled
    from ktbt_proto.tools.ros2.bridge import Bridge
    from ktbt_proto.transport.ros2 import Topics
    from ktbt_proto.transport.zenoh import SessionError

    try:
        rclpy.init(args=[sys.argv[0], *extra], signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:  # rclpy's own error for bad ROS arguments
        raise refuse(f"--ros-args: {exc}".splitlines()[0]) from None
    code = 0
    node: Any = None
    bridge: Any = None
    try:
        with until_signalled() as stop:
            node = rclpy.create_node(node_name)
            # The library's records (the mirrors' refusals) through the node's logger too.
            logs.hear(node, node.get_logger())
            try:
                bridge = Bridge(
                    node,
                    settings,
                    Topics(*topics_given),
                    query_timeout=query_timeout,
                    max_robots=max_robots,
                    policy=policy,
                    trust=store,
                    max_per_source=max_per_source,
                )
            except SessionError as exc:
                raise refuse(str(exc)) from None
            _say(
                f"{bridge.name}: bridging zenoh ({', '.join([*(connect or []), *(listen or [])])})"
                f" and ROS 2 ({topics_given[0]}, {topics_given[1]}); Ctrl-C to stop"
            )
            executor = SingleThreadedExecutor()
            executor.add_node(node)
            while not stop.is_set():
                executor.spin_once(timeout_sec=0.02)
                bridge.step()
    except typer.Exit:
        raise
    except Exception as exc:  # never a traceback: one line
        _say(f"error: {type(exc).__name__}: {exc}".splitlines()[0])
        code = 1
    finally:
        if bridge is not None:
            _say(bridge.summary())
            bridge.close()
        if node is not None:
            logs.unhear(node)
            node.destroy_node()
        try_shutdown()
    raise typer.Exit(code)


def register(app: typer.Typer) -> None:
    app.add_typer(ros2, name="ros2")
