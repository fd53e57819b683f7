"""The state of one trial, as the mechanisms see it: plain arrays, one row per robot (or per
target), and the robots' agents.

``world.World`` builds and owns it and runs one iteration in the release's order
(spec/simulator.md §8.5); each mechanism (``motion``, ``sensing``, ``timers``, ``teaching``, the
behaviours of ``robot``, ``records``) is a function of this state and its inputs, and imports
this module, never ``world``: data flows one way, from the world's orchestration into the
mechanisms and back through the arrays.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np

if TYPE_CHECKING:
    from ktbt_proto.exchange.application import ApplicationTimedAgent
    from ktbt_proto.transport.memory import MemoryNetwork
    from ktbt_sim.scenario import Scenario
    from ktbt_sim.sensing import Proximity, TargetSensor
    from ktbt_sim.timers import Timers


class Trial(Protocol):
    """What the mechanisms read and write. Arrays have one row per robot unless said."""

    scenario: Scenario
    n: int
    iteration: int
    pos: np.ndarray
    """(n, 2) positions, as pymunk last wrote them."""
    drive: np.ndarray
    """The motion each robot's tree last chose (``motion.STOP`` … ``motion.IDLE``); the
    scenario's ``mode`` is the release's mode of learning, a different thing."""
    walk_flag: np.ndarray
    carrying: np.ndarray
    """The target each robot carries, -1 for none."""
    goal: np.ndarray
    """The zone (1..4) each carrier heads for."""
    in_zone: np.ndarray
    known: np.ndarray
    """(n, 4): the colours each robot knows, read back from its agent."""
    collected: np.ndarray
    """(4,): targets counted per colour."""
    delivered: int
    target_colour: np.ndarray
    """(targets,): each target's colour, 1..4."""
    target_free: np.ndarray
    """(targets,): still lying where it was placed."""
    colour_of: np.ndarray
    """(targets + 1,): ``target_colour`` with 0 at index -1 (no target registered)."""
    picked: list[int]
    """Targets taken this iteration, for the world to remove from the physics space."""
    timers: Timers
    querying: np.ndarray
    answering: np.ndarray
    """Robots in a teaching wait (the release's teaching flag)."""
    taught: np.ndarray
    asked: np.ndarray
    """The colour each robot last asked about."""
    requester: np.ndarray
    """Each teacher's requester (§8.2), -1 for none."""
    memory_iter: np.ndarray
    """EL's memory timer (§9.3)."""
    forgotten: int
    heard_from: dict[int, set[int]]
    answered_at: dict[int, int]
    proximity: Proximity
    sensor: TargetSensor
    agents: list[ApplicationTimedAgent]
    names: list[str]
    network: MemoryNetwork
    sequence_keys: list[str]
    """The knowledge key of each colour (index 0: red)."""


def sync_known(trial: Trial, i: int) -> None:
    """Robot ``i``'s colours, read back from its agent's knowledge base."""
    knowledge = trial.agents[i].knowledge
    for c, key in enumerate(trial.sequence_keys):
        trial.known[i, c] = key in knowledge


def forget_learned(trial: Trial, i: int) -> None:
    """EL: robot ``i`` forgets everything it learned at once; its tree reverts to what it was
    built with (§9.3)."""
    trial.forgotten += trial.agents[i].forget_learned(reason="idle")
    sync_known(trial, i)
    trial.memory_iter[i] = 0


def total(trial: Trial, counter: str) -> int:
    """The sum of one of the agents' own ``Metrics`` counters over every robot: the simulator
    keeps no counters of its own for what the agents count."""
    return sum(int(getattr(agent.metrics, counter)) for agent in trial.agents)
