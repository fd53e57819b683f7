"""A KT-BT agent attached to its user's own rclpy node and py_trees tree (spec/protocol.md
section 11, "Embedding"): :func:`attach`.

The user keeps their node, their tree and the timer that ticks it, as with py_trees_ros
(whose ``BehaviourTree.setup(node=...)`` takes an existing node and hands it to every
behaviour's ``setup``). What ``attach`` adds to the node:

- the fleet's topics (:class:`~ktbt_proto.transport.ros2.Ros2Transport`): the robot
  answers every query it can at once, from what it knows at that moment, inside the
  subscription's callback (section 4.5);
- one timer, on the node's executor, that asks for what the robot is missing (the sequences
  given, else what the fleet's catalogs list that its vocabulary can execute) with section
  4.5's backoff, and checks and merges the answers (section 2); and a second, armed only when
  an answer arrives or it is told what to meet, that does the same at once
  (:class:`~ktbt_proto.interop.ros2.stepping.Stepping`);
- what it shows (:class:`~ktbt_proto.interop.ros2.showing.ShownTopics`) under ``~/ktbt``:
  ``events``, ``tree`` and ``catalog``, so the user's own topics keep their names.

The tree learns through :class:`~ktbt_proto.interop.pytrees_control.PyTreesControl` (section
4.4): a learned item is inserted into the placeholder (``Selector(name="k:new",
memory=False)``) from a pre-tick handler, so between two of the user's ticks, and each of its
behaviours is set up with ``setup(node=node)`` first, as py_trees_ros sets up its own: a
learned leaf that is the user's ROS behaviour (an action client, say) finds its node there.
The agent is timed by this timer (an
:class:`~ktbt_proto.exchange.application.ApplicationTimedAgent`, section 4.1): it never ticks
the user's tree. Every callback is in the node's default callback group, so with any executor
none runs while the user's timer (in that group too) ticks the tree.

What the user can get wrong is refused, leaving the node and the tree as they were (what was
added before the refusal is taken off, behaviours set up are shut down), each with one line:
a tree that is not a ``BehaviourTree`` or has no placeholder (``TypeError``, ``ValueError``),
a robot name or topic that is not one, or a name another robot of the fleet already announces
(``ValueError``, naming both nodes), a sequence or a knowledge item its
vocabulary cannot execute (``StringBTError``, with its code).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path

from py_trees import trees
from rclpy.node import Node

from ktbt_proto.blackboard import Blackboard
from ktbt_proto.control import ControlFactory
from ktbt_proto.errors import StringBTError
from ktbt_proto.exchange.answers import catalog
from ktbt_proto.exchange.application import ApplicationTimedAgent
from ktbt_proto.exchange.knowledge import KnowledgeBase, item_slot, learning_slot
from ktbt_proto.exchange.member import FleetMember
from ktbt_proto.exchange.overhearing import Overhear, Overhearing
from ktbt_proto.exchange.security import Security
from ktbt_proto.exchange.transferlog import TransferLog
from ktbt_proto.interop.knowledge_file import load_knowledge
from ktbt_proto.interop.pytrees import Behaviours
from ktbt_proto.interop.pytrees_control import PyTreesControl, known_behaviours, py_trees_control
from ktbt_proto.interop.ros2.logs import hear, speaking, unhear
from ktbt_proto.interop.ros2.showing import FleetCatalogs, Services, ShownTopics
from ktbt_proto.interop.ros2.stepping import Stepping
from ktbt_proto.items import read_sequence, sequence_key, show_key
from ktbt_proto.registry import Registry
from ktbt_proto.transport.ros2 import Ros2Transport, Topics, open_to_strangers, robot_name
from ktbt_proto.tree import Condition, Placeholder, SequenceNode
from ktbt_proto.validate import find_problems

__all__ = ["Embedded", "attach"]

PREFIX = "~/ktbt"
"""Where an embedded robot's events, tree and catalog go, under its user's node."""


def attach(
    node: Node,
    tree: trees.BehaviourTree,
    registry: Registry,
    *,
    name: str | None = None,
    knowledge: KnowledgeBase | str | Path | None = None,
    behaviours: Behaviours | None = None,
    sequences: Iterable[str] | None = None,
    topics: Topics | None = None,
    security: Security | None = None,
    overhear: Overhear = Overhear.OFF,
    wait: float = 2.0,
    period: float = 0.1,
) -> Embedded:
    """Attach a KT-BT agent to ``node`` that learns into and teaches from ``tree``; the user
    goes on ticking ``tree`` from their own timer (see the module's docstring).

    ``registry``: the robot's vocabulary, which received knowledge is checked against (section
    2); ``behaviours``: its own py_trees behaviours by leaf name (known as actions, built with
    the leaf's arguments, :func:`~ktbt_proto.interop.pytrees_control.known_behaviours}`).
    ``name``: the robot's name in messages (default: the node's). ``knowledge``: items (or a
    knowledge file) it starts with and teaches. ``sequences``: what it meets (asked in one
    query); None: what the fleet's catalogs list that its vocabulary can execute (section 4.5).
    ``topics``: the fleet's (default ``/ktbt/...``); ``security``: key pair, trust policy and
    store, transfer log (sections 7, 8); ``overhear``: section 4.3. ``wait``: seconds a query
    stays open; ``period``: seconds between two runs of the agent's timer. Close the handle (or use
    it as a context manager) to take everything off the node again."""
    if not isinstance(node, Node):
        raise TypeError(f"attach takes the user's rclpy Node, not a {type(node).__name__}")
    if not isinstance(registry, Registry):
        raise TypeError(
            f"registry: a ktbt_proto Registry (kp.load_vocabulary('robot.toml')), not a "
            f"{type(registry).__name__}"
        )
    if name is not None and not isinstance(name, str):
        raise ValueError(f"name {name!r}: use 1 to 64 letters, digits, '_', '.', '-'")
    robot = robot_name(node, name)
    if not (0 < wait <= 3600 and 0 < period <= 60):
        raise ValueError(f"wait {wait} s, period {period} s: use (0, 3600] and (0, 60]")
    factory = py_trees_control(tree, behaviours=behaviours, setup_kwargs={"node": node})
    vocabulary = known_behaviours(registry, behaviours or {})
    todo = None if sequences is None else [_meetable(s, vocabulary) for s in sequences]
    items = load_knowledge(knowledge) if isinstance(knowledge, str | Path) else knowledge
    return Embedded(
        node,
        tree,
        robot,
        registry,
        factory,
        items,
        todo,
        topics,
        security or Security(),
        overhear,
        wait,
        period,
    )


def _meetable(text: str, vocabulary: Registry) -> str:
    """A sequence to meet, as its key; one its vocabulary cannot execute could never be
    learned, so it is refused now (``StringBTError``, its code and the part at fault)."""
    conds = read_sequence(text)
    problems = find_problems(SequenceNode(conds), vocabulary)
    if problems:
        first = problems[0]
        raise StringBTError(first.code, f"sequence {text!r}: {first.message}")
    return sequence_key(conds)


class Embedded:
    """A KT-BT agent attached to a user's node and tree (made by :func:`attach`): ``agent``
    (its knowledge, metrics and blackboard), ``transport``, ``name``. :meth:`close` takes it
    off the node and the tree."""

    def __init__(
        self,
        node: Node,
        tree: trees.BehaviourTree,
        name: str,
        registry: Registry,
        factory: ControlFactory,
        knowledge: KnowledgeBase | None,
        todo: list[str] | None,
        topics: Topics | None,
        security: Security,
        overhear: Overhear,
        wait: float,
        period: float,
    ) -> None:
        self.node, self.tree, self.name = node, tree, name
        self.logger = node.get_logger()
        hear(self, self.logger)  # the library's records of this robot through its node's logger
        self.closed = True  # until attached: no step before then
        self._stepping = Stepping(node, self._step)
        try:
            with speaking(self.logger):
                self._build(registry, factory, knowledge, todo, topics, security, overhear, wait)
        except BaseException:
            self._stepping.close()
            unhear(self)
            raise
        self.closed = False
        warning = open_to_strangers(node, name, security.policy)
        if warning is not None:
            self.logger.warning(warning)
        self._timer = node.create_timer(period, self._stepping.tick)
        self.shown.show(self._control.tree)
        self.logger.info(
            f"{name}: KT-BT attached, knows {len(self.agent.knowledge)}, learns into "
            f"k:{self.agent.slot}, will meet "
            f"{'what the fleet lists' if todo is None else f'{len(todo)} sequences'}"
        )

    def _build(
        self,
        registry: Registry,
        factory: ControlFactory,
        knowledge: KnowledgeBase | None,
        todo: list[str] | None,
        topics: Topics | None,
        security: Security,
        overhear: Overhear,
        wait: float,
    ) -> None:
        """The transport, the agent, what it shows and offers, and the fleet member; what was
        made before a refusal is taken off again."""
        node, name = self.node, self.name
        self._own_log = security.log is None
        log = security.log if security.log is not None else TransferLog(None)
        self.transport = Ros2Transport(
            node,
            name,
            topics,
            query_timeout=wait,
            identity=security.identity,
            log=log,
            overhear=overhear != "off",
            arrived=self._stepping.soon,  # an answer is merged at once, not at the next run
        )
        try:
            self.transport.claim("name")  # a name the fleet already has: one line, refused
            self.agent = ApplicationTimedAgent(
                name,
                factory,
                registry,
                self.transport,
                security=replace(security, log=log),
                ear=Overhearing(overhear),
            )
            self._control: PyTreesControl = self.agent.control  # type: ignore[assignment]
            slot = learning_slot(self._control.tree)
            if slot is None:  # py_trees_control refuses a tree without a placeholder first
                raise ValueError("attach: the tree has no knowledge placeholder <k>(...)")
            self.agent.slot = slot
            if knowledge is not None:
                self._start_with(knowledge, slot)
            agent = self.agent
            self.shown = ShownTopics(node, name, catalog(agent.knowledge, security.identity),
                                     log, security.identity, PREFIX)  # fmt: skip
            # Read for what to meet when told none; heard always, each republished catalog as
            # its robot's announcement of what it learned (section 11).
            self._catalogs = FleetCatalogs(
                node, self.shown.catalog_topic, fleet=self.transport.peers
            )
            self.member = FleetMember(
                agent,
                self.transport,
                self._catalogs,
                todo,
                wait=wait,
                cooldown=0.0,
                say=self.logger.info,
                ticks_control=False,  # the user ticks the tree
                relay=self._catalogs,
            )
            self._offered = Services(node, self.member, self.shown, self._show, PREFIX)
        except BaseException:
            for made in ("_catalogs", "shown"):
                if getattr(self, made, None) is not None:
                    getattr(self, made).close()
            self.transport.close()
            self._unhook()
            raise

    def _start_with(self, knowledge: KnowledgeBase, slot: str) -> None:
        """The items it starts knowing, in the placeholders they name (else ``prior``, else its
        learning placeholder), checked against its vocabulary as a merge is."""
        names = {n.name for n, _ in self._control.tree.walk() if isinstance(n, Placeholder)}
        merged: list[tuple[str, tuple[Condition, ...]]] = []
        try:
            for item in knowledge:
                where = item_slot(names, item.segment, slot)
                if not self._control.merge(item.subtree, where, item.conditions):
                    self.node.get_logger().warning(
                        f"{self.name}: {show_key(item.key)} not merged: k:{where} admits no other "
                        "item for its conditions"
                    )
                    continue
                merged.append((where, item.conditions))
                self.agent.knowledge.add(item)
        except BaseException:  # one refused: those merged before it go, shut down
            for where, conditions in merged:
                self._control.forget(where, conditions)
            raise

    @property
    def blackboard(self) -> Blackboard:
        """The blackboard its registry's conditions and actions read (flags, say)."""
        return self.agent.blackboard

    @property
    def wait(self) -> float:
        """Seconds a query stays open (settable)."""
        return self.member.wait

    @wait.setter
    def wait(self, seconds: float) -> None:
        self.member.timing(seconds, self.member.cooldown)
        self.transport.query_timeout = seconds

    @property
    def todo(self) -> list[str]:
        """The sequence keys it is still to meet."""
        return self.member.todo

    def knows(self, sequence: Iterable[str] | str) -> bool:
        return self.agent.knows(sequence)

    def meet(self, *sequences: str) -> None:
        """Meet these sequences too (checked as :func:`attach` checks its ``sequences``)."""
        vocabulary = self.agent.registry
        self.member.meet([_meetable(s, vocabulary) for s in sequences])
        self._stepping.soon()  # asked at once

    def _step(self, tick: bool) -> None:
        """One run of the agent's timer (``tick``), or a step between two (an answer arrived,
        or it was told what to meet): a step of the fleet member (section 4.5) on the user's
        tick count, then what changed is shown. Nothing once closed, or once the node's context
        is shut down (a signal, ``rclpy.shutdown``): the executor may still run a timer that was
        due, and its entities can no longer be read."""
        if self.closed or not self.node.context.ok():
            return
        if not tick and self.transport.clock() <= 0:
            return  # a simulation's clock not started: its timer does not run either
        self.agent.now = self.tree.count
        with speaking(self.logger):  # the library's records of this robot: its node's
            try:
                self.member.step(self.transport.clock(), tick=tick)
                self._show()
            except Exception:
                if self.node.context.ok():
                    raise  # shut down while stepping: nothing to report

    def _show(self) -> None:
        self.shown.show(self._control.tree)

    def _unhook(self) -> None:
        control = getattr(self, "_control", None)
        if control is not None and control._apply in self.tree.pre_tick_handlers:
            self.tree.pre_tick_handlers.remove(control._apply)

    def close(self) -> None:
        """Take the agent off the node (its timer, topics and publishers) and the tree (its
        pre-tick handler): the node and the tree go on as the user's, items learned kept."""
        if self.closed:
            return
        self.closed = True
        unhear(self)
        self.node.destroy_timer(self._timer)
        self._stepping.close()
        self._offered.close()
        if self._catalogs is not None:
            self._catalogs.close()
        self.shown.close()
        self.transport.close()
        self._unhook()
        if self._own_log and self.agent.log is not None:
            self.agent.log.close()

    def __enter__(self) -> Embedded:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()
