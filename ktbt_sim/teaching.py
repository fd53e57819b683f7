"""Knowledge transfer as the release does it (``spec/simulator.md`` §8), over real messages.

The robots' agents are application-timed (``ApplicationTimedAgent``, ``spec/protocol.md``
section 4.1). Each iteration, after the behaviour trees and the actuators (§8.5):

1. **Comms scan** (§8.2): every robot that is not querying and has neighbours takes as its
   requester the first neighbour, in order of entry into range, that is querying and not yet
   taught (none if there is none). A robot with no neighbours, or querying itself, keeps the
   requester it had: a stale requester can still be answered.
2. **Asking** (§8.1): a free robot (neither waiting nor cooling down) that has registered a
   target, carries nothing and does not know the target's colour broadcasts a query
   (``ask``) and starts a wait. A query stays answerable for the whole wait: when a robot
   comes into range of an asker still untaught, the asker sends it the query
   (``announce``), as if it had heard it all along.
3. **Waits that ended** close their queries (``close_query``: a query never answered is
   lost) and clear the querying and teaching flags (§7).
4. **TeachingRule** (§8.2, §8.3): a free robot that is not querying, carries nothing and has a
   requester answers it (``answer``) if it knows what the requester asked, the requester
   is still untaught and knows fewer colours than the memory size. It answers nobody else, even
   a later neighbour it could answer. A requester a teacher still holds after it moved out of
   range can be answered, and hears new questions from it too (the release's teacher reads
   its requester's question wherever it is). The learner's agent checks and merges the answer
   (``receive``); a taught learner is skipped by every later teacher, so there is exactly
   one teacher per query. The teacher then waits and cools down; the learner keeps waiting for
   the rest of its wait.

The ``broadcast`` teaching rule differs only in step 1: a teacher's requester is the first
untaught querying neighbour whose question it can answer.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ktbt_sim import robot as rb
from ktbt_sim.kernel import jit
from ktbt_sim.scenario import Mode, TeachingRule
from ktbt_sim.sensing import first_requesters
from ktbt_sim.state import sync_known

if TYPE_CHECKING:
    from ktbt_sim.state import Trial


def step(world: Trial, t: int) -> None:
    """Steps 1 to 4 and the passive modes' listening, in the release's order. The array work
    of steps 1 to 4 is one compiled call (two when a robot asks, since asking changes what
    step 3 reads); the agents' messages and merges stay in Python."""
    timers, prox = world.timers, world.proximity
    refuse = world.scenario.memory_when_full == "refuse"
    cap = world.scenario.memory_size if refuse else -1
    askers, closers, can = prepare(
        prox.has_neighbours, world.querying, world.taught, world.requester, prox.keys,
        prox.entered, world.known, world.asked, world.scenario.teaching is TeachingRule.BROADCAST,
        world.sensor.tsr, timers.cool_end, 2 * t + 1, world.carrying, world.colour_of,
        world.answering, timers.wait_end, cap,
    )  # fmt: skip
    if len(askers):
        _ask(world, t, askers)
        closers = _ended(world.querying, world.answering, timers.wait_end, 2 * t + 1)
        can = _teachers(
            world.requester, timers.cool_end, 2 * t + 2, world.querying, world.carrying,
            world.taught, world.known, world.asked, cap,
        )  # fmt: skip
    for i in closers.tolist():  # step 3: a query never answered is lost
        world.agents[i].close_query()
    if len(can):
        _teach(world, t, can)
    mode = world.scenario.mode
    if mode is Mode.PASSIVE_BUFFER or mode is Mode.PASSIVE:
        _overhear(world, t)
        if mode is Mode.PASSIVE_BUFFER:
            _use_buffer(world, t)


@jit
def prepare(
    has_neighbours: np.ndarray,
    querying: np.ndarray,
    taught: np.ndarray,
    requester: np.ndarray,
    keys: np.ndarray,
    entered: np.ndarray,
    known: np.ndarray,
    asked: np.ndarray,
    broadcast: bool,
    tsr: np.ndarray,
    cool_end: np.ndarray,
    call: int,
    carrying: np.ndarray,
    colour_of: np.ndarray,
    answering: np.ndarray,
    wait_end: np.ndarray,
    cap: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 1 (:func:`scan`) and who asks in step 2 (:func:`_askers`, ``call`` = 2t + 1). When
    nobody asks, also step 3's flags (:func:`_ended`) and step 4's teachers (:func:`_teachers`);
    when somebody does, those are left empty for after the questions."""
    scan(has_neighbours, querying, taught, requester, keys, entered, known, asked, broadcast)
    askers = _askers(tsr, cool_end, call, carrying, colour_of, known)
    none = np.zeros(0, np.int64)
    if len(askers):
        return askers, none, none
    closers = _ended(querying, answering, wait_end, call)
    can = _teachers(requester, cool_end, call + 1, querying, carrying, taught, known, asked, cap)
    return askers, closers, can


@jit
def scan(
    has_neighbours: np.ndarray,
    querying: np.ndarray,
    taught: np.ndarray,
    requester: np.ndarray,
    keys: np.ndarray,
    entered: np.ndarray,
    known: np.ndarray,
    asked: np.ndarray,
    broadcast: bool,
) -> None:
    """Every robot that is not querying and has neighbours takes as its requester the first
    neighbour in order of entry with an open query (with ``broadcast``, only one whose
    question it can answer), or none."""
    n = querying.shape[0]
    open_ = querying & ~taught
    if open_.any():
        first = first_requesters(keys, entered, n, open_, known, asked, broadcast)
    else:
        first = np.full(n, -1, np.int64)
    for i in range(n):
        if has_neighbours[i] and not querying[i]:
            requester[i] = first[i]


def _ask(world: Trial, t: int, askers: np.ndarray) -> None:
    """Step 2: ``RegLearnBT`` after its counter call ``2t``: ``askers`` ask."""
    tsr = world.sensor.tsr
    buffered = world.scenario.mode is Mode.PASSIVE_BUFFER
    for i in askers.tolist():
        colour = int(world.colour_of[tsr[i]])
        if buffered and rb.sequence_of(colour) in world.agents[i].buffered:
            continue  # PLB does not ask about what it overheard: it learns it (§9.5)
        agent = world.agents[i]
        agent.now = t
        agent.ask(rb.sequence(colour))
        # A teacher that still holds this robot as its (stale) requester reads its question in
        # the release wherever it is: send it there too.
        for teacher in np.flatnonzero(world.requester == i).tolist():
            if not world.proximity.in_range(i, teacher):
                agent.announce(world.names[teacher])
        world.asked[i] = colour
        world.querying[i] = True
        world.taught[i] = False
        world.walk_flag[i] = False
        world.timers.start(i, 2 * t + 1)


@jit
def _askers(
    tsr: np.ndarray,
    cool_end: np.ndarray,
    call: int,
    carrying: np.ndarray,
    colour_of: np.ndarray,
    known: np.ndarray,
) -> np.ndarray:
    """The free robots (not busy before ``call``) that have registered a target, carry
    nothing and do not know the target's colour."""
    out = np.empty(tsr.shape[0], np.int64)
    k = 0
    for i in range(tsr.shape[0]):
        free = tsr[i] >= 0 and cool_end[i] < call and carrying[i] < 0
        if free and not known[i, colour_of[tsr[i]] - 1]:
            out[k] = i
            k += 1
    return out[:k]


@jit
def _ended(
    querying: np.ndarray, teaching: np.ndarray, wait_end: np.ndarray, call: int
) -> np.ndarray:
    """Clear the querying and teaching flags of the waits that ended by ``call``; returns the
    robots whose query closed."""
    out = np.empty(querying.shape[0], np.int64)
    k = 0
    for i in range(querying.shape[0]):
        if wait_end[i] <= call:
            if querying[i]:
                querying[i] = False
                out[k] = i
                k += 1
            teaching[i] = False
    return out[:k]


def _teach(world: Trial, t: int, can: np.ndarray) -> None:
    """Step 4: ``TeachBT`` after its counter call ``2t + 1``: the robots ``can`` may teach."""
    memory = world.scenario.memory_size
    for teacher in can.tolist():
        learner = int(world.requester[teacher])
        if not world.querying[learner] or world.taught[learner]:
            continue
        colour = int(world.asked[learner])
        if not world.known[teacher, colour - 1]:
            continue
        if world.scenario.memory_when_full == "refuse" and world.known[learner].sum() >= memory:
            continue
        world.agents[teacher].receive()
        query = world.agents[teacher].heard(world.names[learner])
        asked = world.agents[learner].open_query
        if query is None or asked is None or query.id != asked.id:
            continue  # never heard this question
        if not world.agents[teacher].answer(query):
            continue
        world.agents[learner].now = t
        world.answering[teacher] = True
        world.walk_flag[teacher] = False
        world.timers.start(teacher, 2 * t + 2)
        world.heard_from[teacher] = set()
        world.answered_at[teacher] = t
        if world.agents[learner].receive():
            world.taught[learner] = True
            world.memory_iter[learner] = 0
            sync_known(world, learner)


@jit
def _teachers(
    requester: np.ndarray,
    cool_end: np.ndarray,
    call: int,
    querying: np.ndarray,
    carrying: np.ndarray,
    taught: np.ndarray,
    known: np.ndarray,
    asked: np.ndarray,
    cap: int,
) -> np.ndarray:
    """The robots with a requester that are free before ``call``, not querying and carry
    nothing, whose requester is querying, untaught, asked a colour the robot knows and knows
    fewer than ``cap`` colours (-1: no cap). Step 4 checks the requester again as it goes (a
    lesson teaches it); nothing it does makes a robot left out here a teacher."""
    out = np.empty(requester.shape[0], np.int64)
    k = 0
    for i in range(requester.shape[0]):
        if requester[i] >= 0 and cool_end[i] < call and not querying[i] and carrying[i] < 0:
            learner = requester[i]
            if not querying[learner] or taught[learner] or not known[i, asked[learner] - 1]:
                continue
            if cap >= 0 and known[learner].sum() >= cap:
                continue
            out[k] = i
            k += 1
    return out[:k]


def came_into_range(world: Trial, pairs: np.ndarray) -> None:
    """Askers still untaught send their query to each robot that just came into range."""
    open_ = world.querying & ~world.taught
    if not open_.any():
        return
    for i, j in pairs.tolist():
        if open_[i]:
            world.agents[i].announce(world.names[j])


def _overhear(world: Trial, t: int) -> None:
    """§9.4: every robot that is not querying hears the answer of each teaching neighbour, for
    the teacher's whole teaching wait; PLB keeps it, PL learns it at once (§9.6). With
    ``overhear_window = "answer"`` (our variant, a radio's) only the robots in range at the
    moment of the answer hear it."""
    teachers = np.flatnonzero(world.answering)
    if not len(teachers):
        return
    moment = world.scenario.overhear_window == "answer"
    for teacher in teachers.tolist():
        answer = world.agents[teacher].last_answer
        if answer is None or (moment and world.answered_at.get(teacher) != t):
            continue
        heard = world.heard_from.setdefault(teacher, set())
        for listener in world.proximity.neighbours(teacher).tolist():
            if listener in heard or world.querying[listener]:
                continue
            heard.add(listener)
            agent = world.agents[listener]
            world.agents[teacher].transport.send(world.names[listener], answer)
            agent.now = t
            if agent.receive():
                world.memory_iter[listener] = 0
                sync_known(world, listener)


def _use_buffer(world: Trial, t: int) -> None:
    """§9.5: a robot that has registered a target of a colour it does not know, and carries
    nothing, learns that colour from its buffer at once, without a query or a wait."""
    tsr = world.sensor.tsr
    ready = (tsr >= 0) & (world.carrying < 0) & world.sensor.enabled
    if not ready.any():
        return
    colours = world.colour_of[tsr]
    for i in np.flatnonzero(ready).tolist():
        colour = int(colours[i])
        if world.known[i, colour - 1]:
            continue
        agent = world.agents[i]
        if rb.sequence_of(colour) not in agent.buffered:
            continue
        agent.now = t
        if agent.learn_buffered(rb.sequence(colour)):
            world.memory_iter[i] = 0
            sync_known(world, i)
