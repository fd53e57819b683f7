"""``ktbt ros2 run``: one robot's KT-BT agent as a managed (lifecycle) ROS 2 node
(spec/protocol.md section 11, "ROS 2 binding").

The node does what ``ktbt peer run`` does on zenoh (section 4.5): it starts with a control tree,
a vocabulary and, if given, a knowledge file; asks the fleet for every sequence it lacks in one
query, at once when a new robot appears and with a bounded backoff after a query nobody
answered (``Learner``); and teaches what it knows, answering at once from its knowledge. As a
managed node it does so only while active:

- ``configure`` reads the parameters, loads the files and builds the agent and its topics;
  anything wrong fails the transition with one line in the log;
- ``activate`` starts ticking; an inactive node neither asks nor answers;
- ``deactivate`` stops ticking; ``cleanup`` drops everything ``configure`` made.

What it shows: its fleet events (section 10) on ``~/events``; its control tree, latched
(TRANSIENT_LOCAL, depth 1), on ``~/tree`` with a ``changed`` flag, when it activates and after
each merge or forget; its catalog, latched, on ``~/catalog``. Services: ``~/list_knowledge``
and ``~/forget``. It logs through the node's logger, the library's own log records of its
work included (:mod:`ktbt_proto.interop.ros2.logs`): once each, however many nodes a process
runs, at the node's level.
"""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import ParameterUninitializedException
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.node import Node
from rclpy.parameter import Parameter

from ktbt_proto.errors import StringBTError
from ktbt_proto.exchange.answers import catalog
from ktbt_proto.exchange.application import ApplicationTimedAgent
from ktbt_proto.exchange.knowledge import with_knowledge
from ktbt_proto.exchange.member import FleetMember
from ktbt_proto.exchange.overhearing import Overhear, Overhearing
from ktbt_proto.exchange.security import Security
from ktbt_proto.exchange.signing import Identity, KeyFileError
from ktbt_proto.exchange.transferlog import TransferLog
from ktbt_proto.exchange.trust import Policy, TrustStore
from ktbt_proto.interop.knowledge_file import load_knowledge
from ktbt_proto.interop.ros2.logs import hear, speaking, unhear
from ktbt_proto.interop.ros2.showing import (
    FleetCatalogs,
    Services,
    ShownTopics,
    event_json,
    event_msg,
    events_qos,
    latched,
)
from ktbt_proto.interop.ros2.stepping import Stepping
from ktbt_proto.interop.sidecar import LearnedExport, tree_ids
from ktbt_proto.items import read_sequence, sequence_key
from ktbt_proto.tools.robot import build_robot
from ktbt_proto.transport.ros2 import Ros2Transport, Topics, open_to_strangers, robot_name
from ktbt_proto.tree import SequenceNode
from ktbt_proto.validate import find_problems

__all__ = ["SETUP", "KtbtNode", "event_json", "event_msg", "events_qos", "latched", "problem"]

SETUP = (
    "agent_name",
    "control",
    "vocabulary",
    "knowledge",
    "save",
    "key",
    "policy",
    "trust",
    "log",
    "overhear",
    "wait_ticks",
    "cooldown_ticks",
    "queries_topic",
    "answers_topic",
    "errors_topic",
    "export_learned",
)
"""Parameters read when the node is configured: changed only while it is unconfigured."""


def problem(name: str, value: Any) -> str | None:
    """What is wrong with a value of the node's parameter ``name``, in one line, or None. A
    number may be given as an integer where a float is declared (``tick_rate:=50``)."""
    number = (
        float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None
    )
    if name == "tick_rate" and (number is None or not 0 < number <= 1000):
        return f"tick_rate {value!r}: use a number of Hz in (0, 1000]"
    if name == "snapshot_period" and (number is None or not 0 <= number <= 3600):
        return f"snapshot_period {value!r}: use a number of seconds in [0, 3600] (0: on change)"
    if name in ("wait_ticks", "cooldown_ticks") and (
        not isinstance(value, int) or isinstance(value, bool) or not 1 <= value <= 1_000_000
    ):
        return f"{name} {value!r}: use 1 to 1000000 ticks"
    if name == "overhear" and value not in ("off", "update", "buffer"):
        return f"overhear {value!r}: use off, update or buffer"
    if name == "policy" and value not in [p.value for p in Policy]:
        return f"policy {value!r}: use {', '.join(p.value for p in Policy)}"
    if name.endswith("_topic") and not str(value).startswith("/"):
        return f"{name} {value!r}: use an absolute name, shared by the fleet (/ktbt/queries)"
    if name == "sequences":
        for text in value or ():
            try:
                read_sequence(text)
            except StringBTError as err:
                return f"sequences: {text!r}: {err.code} {err.message}"
    return None


class KtbtNode(LifecycleNode):
    """One robot's agent as a managed node (see the module's docstring)."""

    def __init__(self, node_name: str = "ktbt", **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.logger = Node.get_logger(self)
        """The node's logger (named for the node, namespace included)."""

        def declare(name: str, default: Any, when: str, **limits: Any) -> None:
            # One descriptor each: rclpy writes the parameter's type into the one it is given.
            descriptor = ParameterDescriptor(description=when, **limits)
            self.declare_parameter(name, default, descriptor)

        def ticks() -> dict[str, Any]:
            return {"integer_range": [IntegerRange(from_value=1, to_value=1_000_000, step=1)]}

        def seconds(most: float) -> dict[str, Any]:
            # An integer is a number too (tick_rate:=50): typed dynamically, checked by problem.
            return {
                "dynamic_typing": True,
                "additional_constraints": f"a number from 0 to {most:g}",
            }

        setup, live = "read at configure", "applied at once"
        declare("agent_name", "", setup)  # "": the namespace's last name, else the node's
        declare("vocabulary", "", setup)  # FILE.toml or module:callable; "": the demo robot
        declare("control", "", setup)  # a .sbt file; "": the demo's, or a learner's
        declare("knowledge", "", setup)
        declare("save", "", setup)
        declare("key", "", setup)
        declare("policy", "any", setup)
        declare("trust", "", setup)
        declare("log", "", setup)
        declare("overhear", "off", setup)
        declare("wait_ticks", 200, setup, **ticks())
        declare("cooldown_ticks", 50, setup, **ticks())
        declare("queries_topic", Topics().queries, setup)
        declare("answers_topic", Topics().answers, setup)
        declare("errors_topic", Topics().errors, setup)
        declare("export_learned", "", setup)  # a folder: learned items as BT.CPP files (Nav2)
        self.declare_parameter(
            "tree_ids",
            Parameter.Type.STRING_ARRAY,
            ParameterDescriptor(description=f"{setup}; ID=CONDITIONS: an exported item's tree ID"),
        )
        # Unset (typed, no value): meet what the fleet's catalogs list (section 4.5).
        self.declare_parameter(
            "sequences",
            Parameter.Type.STRING_ARRAY,
            ParameterDescriptor(description=f"{live}; unset: what the fleet's catalogs list"),
        )
        declare("tick_rate", 100.0, f"{live}; Hz", **seconds(1000))
        declare("snapshot_period", 0.0, f"{live}; seconds, 0: only on change", **seconds(3600))
        self.add_on_set_parameters_callback(self._on_parameters)
        self.add_post_set_parameters_callback(self._parameters_set)
        hear(self, self.logger)  # the library's records, this node's own through its logger
        self.finalized = False
        """Shut down (the lifecycle's finalized state): the process running it may end."""
        self.agent: ApplicationTimedAgent | None = None
        self.member: FleetMember | None = None
        self.transport: Ros2Transport | None = None
        self.log: TransferLog | None = None
        self._offered: Services | None = None
        self._timer: Any = None
        self._snapshot_timer: Any = None
        self._shown: ShownTopics | None = None
        self._catalogs: FleetCatalogs | None = None
        self._stepping: Stepping | None = None

    # -- parameters -----------------------------------------------------------------------------

    def _on_parameters(self, params: list[Parameter]) -> SetParametersResult:
        """Whether the new values may be set: setup parameters change only while unconfigured,
        and every value must be one the node takes (:func:`problem`). Nothing changes here:
        what a value does is done once it is set (:meth:`_parameters_set`), as rclpy asks."""
        for param in params:
            if param.name in (*SETUP, "tree_ids") and self.agent is not None:
                why: str | None = f"{param.name} is read at configure: clean up first"
            else:
                why = problem(param.name, param.value)
            if why is not None:
                return SetParametersResult(successful=False, reason=why)
        return SetParametersResult(successful=True)

    def _parameters_set(self, params: list[Parameter]) -> None:
        """The live ones apply at once: the sequences to meet, the tick rate and the snapshot
        period (timers made anew)."""
        for param in params:
            if param.name == "sequences" and self.member is not None:
                # told what to meet: the catalogs are no longer read; it asks at once
                self.member.tell(sequence_key(read_sequence(s)) for s in param.value)
                if self._stepping is not None:
                    self._stepping.soon()
        if self._timer is not None and any(
            p.name in ("tick_rate", "snapshot_period") for p in params
        ):
            values = {p.name: p.value for p in params}
            self._start_timers(
                float(values.get("tick_rate", self._param("tick_rate"))),
                float(values.get("snapshot_period", self._param("snapshot_period"))),
            )

    def _param(self, name: str) -> Any:
        """A parameter's value; None when unset (``-p sequences:=[]`` leaves an array
        parameter of a type ROS cannot tell without a value, as unset as none)."""
        try:
            return self.get_parameter_or(name, Parameter(name, value=None)).value
        except ParameterUninitializedException:
            return None

    # -- lifecycle ------------------------------------------------------------------------------

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Build the robot from its parameters; anything wrong fails the transition with one
        line in the log, and the node stays unconfigured."""
        try:
            with speaking(self.logger):
                self._configure()
        except Exception as exc:  # a bad file or value: one line, never a traceback
            if isinstance(exc, OSError) and exc.filename is not None:
                reason = f"{exc.filename}: {exc.strerror}"
            elif isinstance(exc, OSError | ValueError | KeyFileError | StringBTError):
                reason = str(exc)
            else:
                reason = f"{type(exc).__name__}: {exc}"
            self.logger.error(f"configure failed: {' '.join(reason.split())[:300]}")
            with speaking(self.logger):
                self._cleanup()
            return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def _configure(self) -> None:
        for param_name in (*SETUP, "sequences", "tick_rate", "snapshot_period"):
            why = problem(param_name, self._param(param_name))
            if why is not None:
                raise ValueError(why)
        name = robot_name(self, str(self._param("agent_name")), "agent_name")
        vocabulary, control_path = str(self._param("vocabulary")), str(self._param("control"))
        robot = build_robot(vocabulary or None, control_path or None)  # RobotError: one line
        registry, control, slot = robot.registry, robot.control, robot.slot
        for text in self._param("sequences") or ():  # never learnable: refused now, with its code
            found = find_problems(SequenceNode(read_sequence(text)), registry)
            if found:
                raise ValueError(f"sequences: {text!r}: {found[0].code} {found[0].message}")
        knowledge = load_knowledge(self._param("knowledge")) if self._param("knowledge") else None
        key = str(self._param("key"))
        identity = Identity.load(key) if key else None
        policy = Policy(str(self._param("policy")))
        trust_path = str(self._param("trust"))
        trust = TrustStore.load(trust_path) if trust_path else None
        if policy == Policy.TRUSTED and trust is None:
            raise ValueError("policy trusted needs a trust file (parameter trust)")
        overhear = Overhear(str(self._param("overhear")))  # checked by problem() first
        sequences = self._param("sequences")
        todo = None if sequences is None else [sequence_key(read_sequence(s)) for s in sequences]
        wait_ticks, cooldown_ticks = (
            int(self._param("wait_ticks")),
            int(self._param("cooldown_ticks")),
        )
        log_path = str(self._param("log"))
        self.log = TransferLog(log_path or None)
        topics = Topics(
            str(self._param("queries_topic")),
            str(self._param("answers_topic")),
            str(self._param("errors_topic")),
        )
        self._stepping = Stepping(self, self._step)
        self.transport = Ros2Transport(
            self,
            name,
            topics,
            query_timeout=wait_ticks / float(self._param("tick_rate")),
            identity=identity,
            log=self.log,
            overhear=overhear != "off",
            active=False,
            arrived=self._stepping.soon,  # an answer is merged at once, not at the next tick
        )
        self.transport.claim("agent_name")  # a name the fleet already has: one line, refused
        save = str(self._param("save"))
        try:
            self.agent = ApplicationTimedAgent(
                name,
                with_knowledge(control, knowledge, slot),
                registry,
                self.transport,
                knowledge_path=save or None,
                security=Security(identity, policy, trust, self.log),
                ear=Overhearing(overhear),
                slot=slot,
            )
        except StringBTError as err:  # the control tree, with its knowledge, against the registry
            where = control_path or "the demo's control tree"
            why = f"control {where}:{err.line}:{err.column}: {err.code} {err.message}"
            raise ValueError(why) from None
        agent = self.agent  # attached: the transport answers from what it knows (section 4.5)
        self._shown = ShownTopics(
            self, name, catalog(agent.knowledge, identity), self.log, identity
        )
        # Read for what to meet when told none; heard by every robot, each republished catalog
        # as its robot's announcement of what it learned (section 11).
        self._catalogs = FleetCatalogs(self, self._shown.catalog_topic, fleet=self.transport.peers)
        for _, reason in agent.metrics.refusals:  # a damaged save file, say
            self.logger.warning(f"{name} refused: {reason}")
        rate = float(self._param("tick_rate"))
        self.member = FleetMember(
            agent,
            self.transport,
            self._catalogs,
            todo,
            wait=wait_ticks / rate,
            cooldown=cooldown_ticks / rate,
            say=self.logger.info,
            export=self._learned_export(),
            relay=self._catalogs,
        )
        self._offered = Services(self, self.member, self._shown, self._show)
        meets = "what the fleet's catalogs list" if todo is None else f"{len(todo)} sequences"
        self.logger.info(
            f"{name}: configured, knows {len(agent.knowledge)}, will meet {meets}; "
            f"queries on {topics.queries}, answers on {topics.answers}"
        )

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self.transport is None:  # lifecycle allows activate only after configure
            return TransitionCallbackReturn.FAILURE
        self.transport.active = True
        if self.agent is not None:
            warning = open_to_strangers(self, self.transport.name, self.agent.security.policy)
            if warning is not None:
                self.logger.warning(warning)
        self._start_timers(float(self._param("tick_rate")), float(self._param("snapshot_period")))
        if self._stepping is not None:  # what was asked for while inactive stepped nothing
            self._stepping.again()
        self._show(periodic=True)  # a snapshot on every activation, changed or not
        self.logger.info(f"{self.transport.name}: active")
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop_timers()
        if self.transport is not None:
            self.transport.active = False
            self.logger.info(f"{self.transport.name}: inactive")
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        with speaking(self.logger):
            self._cleanup()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Finalized: ``ktbt ros2 run`` ends once the transition is answered; on Ctrl-C or
        SIGTERM it takes this transition itself before it ends."""
        self.logger.info(f"shutting down from {state.label}")
        with speaking(self.logger):
            self._cleanup()
        self.finalized = True
        return TransitionCallbackReturn.SUCCESS

    def _start_timers(self, tick_rate: float, snapshot_period: float) -> None:
        """Tick at ``tick_rate`` (a query stays open ``wait_ticks`` ticks), and publish a
        snapshot every ``snapshot_period`` seconds if positive."""
        self._stop_timers()
        self._timer = self.create_timer(1.0 / tick_rate, self._tick)
        if snapshot_period > 0:
            self._snapshot_timer = self.create_timer(
                snapshot_period, lambda: self._show(periodic=True)
            )
        if self.transport is not None:
            self.transport.query_timeout = int(self._param("wait_ticks")) / tick_rate
        if self.member is not None:  # the wait and the cool-down are counted in ticks
            self.member.timing(
                int(self._param("wait_ticks")) / tick_rate,
                int(self._param("cooldown_ticks")) / tick_rate,
            )

    def _stop_timers(self) -> None:
        for timer in (self._timer, self._snapshot_timer):
            if timer is not None:
                self.destroy_timer(timer)
        self._timer = self._snapshot_timer = None

    def _learned_export(self) -> LearnedExport | None:
        """The ``export_learned`` folder, with ``tree_ids`` (spec/stringbt.md section 12.2):
        what the robot learns, as BehaviorTree.CPP files a Nav2 ``NavigateToPose`` goal names
        by tree ID; a folder it cannot write into or an ID it cannot use fails configure."""
        folder, given = str(self._param("export_learned")), self._param("tree_ids") or []
        if not folder:
            if given:
                raise ValueError("tree_ids: names exported trees; give export_learned")
            return None
        try:
            return LearnedExport(folder, tree_ids(given))
        except OSError as exc:
            raise ValueError(f"export_learned {folder}: {exc.strerror or exc}") from None
        except StringBTError as err:
            raise ValueError(f"tree_ids: {err.code} {err.message}") from None
        except ValueError as exc:
            raise ValueError(f"tree_ids: {exc}") from None

    def _cleanup(self) -> None:
        """Undo ``configure``; the summary of what the agent did goes to the log."""
        self._stop_timers()
        if self.member is not None and self.transport is not None:
            m = self.member.agent.metrics
            self.logger.info(
                f"{self.member.name}: queries sent {m.queries_sent}, answers "
                f"{m.responses_received}, lost {m.queries_lost}, refused "
                f"{self.member.refused + self.transport.refused}, taught "
                f"{m.responses_sent + self.transport.answered}, late answers {m.late_answers}"
            )
        if self.transport is not None:
            self.transport.close()
        if self._stepping is not None:
            self._stepping.close()
        if self._shown is not None:
            self._shown.close()
        if self._catalogs is not None:
            self._catalogs.close()
        if self._offered is not None:
            self._offered.close()
        if self.log is not None:
            self.log.close()
        self.agent, self.transport, self.log, self.member = None, None, None, None
        self._shown = self._catalogs = self._offered = self._stepping = None

    def destroy_node(self) -> None:
        with speaking(self.logger):
            self._cleanup()
        unhear(self)
        super().destroy_node()  # type: ignore[no-untyped-call]

    # -- running --------------------------------------------------------------------------------

    def _tick(self) -> None:
        """A tick of the node's timer: a step of the fleet member (:meth:`_step`)."""
        if self._stepping is not None:
            self._stepping.tick()

    def _step(self, tick: bool) -> None:
        """One step of the fleet member (section 4.5), then what changed is shown: at a tick,
        or between two (``tick`` False, :class:`Stepping`: an answer arrived, or it was told its
        sequences) while active and its clock runs (a simulation's clock started); nothing
        once the context is shut down (a timer that was due may still run)."""
        member, transport = self.member, self.transport
        if member is None or transport is None or not self.context.ok():
            return
        if not tick and (not transport.active or transport.clock() <= 0):
            return
        if tick:
            member.agent.now += 1
        with speaking(self.logger):  # the library's records of this robot: its node's
            try:
                # the node's clock: sim time under use_sim_time
                member.step(transport.clock(), tick=tick)
                self._show()
            except Exception:
                if self.context.ok():
                    raise  # shut down while stepping: nothing to report

    def _show(self, periodic: bool = False) -> None:
        """Publish the tree snapshot and the catalog when they changed (the snapshot on the
        snapshot period even if not: ``changed`` false); nothing while inactive (an item
        forgotten then is shown at the next activation, which publishes a snapshot)."""
        active = self.transport is not None and self.transport.active
        if active and self.agent is not None and self._shown is not None:
            self._shown.show(self.agent.control.tree, periodic)
