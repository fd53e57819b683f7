"""The robot a host runs, built one way from the settings every host takes (``spec/protocol.md``
section 4.5): its vocabulary (a vocabulary file, or a Python registry as ``module:callable``),
its control tree (a stringBT file, which must hold a placeholder) and the placeholder it learns
into; given neither, the search-and-rescue demo robot; given a vocabulary alone, a learner that
runs only what it knows. ``ktbt peer run`` and ``ktbt fleet run`` build it from their options,
the ROS 2 lifecycle node from its parameters; each names the setting at fault its own way
(``--control`` on the command line, ``control`` for a parameter).

The vocabulary is loaded by :func:`~ktbt_proto.tools.vocabulary.load_vocabulary`, the one
loader of a vocabulary file or a Python registry named ``module:callable``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ktbt_proto.errors import StringBTError
from ktbt_proto.exchange.knowledge import learning_slot
from ktbt_proto.files import read_at_most
from ktbt_proto.limits import DEFAULT_LIMITS
from ktbt_proto.registry import Registry
from ktbt_proto.syntax import parse
from ktbt_proto.tools.demo import DEMO_CONTROL, demo_registry
from ktbt_proto.tools.vocabulary import load_vocabulary
from ktbt_proto.validate import find_problems

__all__ = ["LEARNER_CONTROL", "Robot", "RobotError", "build_robot"]

LEARNER_CONTROL = "<sl><k>(prior)<e><k>(new)<e><e>"
"""The control tree of a robot given a vocabulary but no control tree: it runs only what it
knows (what a learner beside a BehaviorTree.CPP program, ``--export-learned``, needs)."""


@dataclass(frozen=True)
class Robot:
    """What a host runs: the robot's vocabulary, its control tree as stringBT and the
    placeholder learned items go into."""

    registry: Registry
    control: str
    slot: str
    vocabulary: str | None = None
    """The vocabulary given (None: the demo robot's)."""


class RobotError(ValueError):
    """The settings describe no robot; the message is one line naming the setting."""


def build_robot(
    vocabulary: str | None,
    control: str | Path | None,
    demo: bool = False,
    named: Callable[[str], str] = str,
) -> Robot:
    """The robot the settings describe (see the module's docstring); ``named`` gives a
    setting's name as its host spells it. Raises :class:`RobotError`."""
    if demo and (vocabulary is not None or control is not None):
        raise RobotError(
            f"{named('demo')}: the demo robot has its own; leave out {named('vocabulary')} "
            f"and {named('control')}"
        )
    if vocabulary is None and control is not None:
        raise RobotError(
            f"{named('control')} {control}: give {named('vocabulary')} too (the names its "
            "tree runs)"
        )
    if vocabulary is None:
        return Robot(demo_registry(), DEMO_CONTROL, "new")
    looks_like_file = vocabulary.endswith(".toml") or ":" not in vocabulary
    if looks_like_file and not Path(vocabulary).is_file():
        raise RobotError(
            f"{named('vocabulary')}: {vocabulary} not found (a FILE.toml, or module:callable)"
        )
    try:
        registry = load_vocabulary(vocabulary)
    except ValueError as exc:
        raise RobotError(f"{named('vocabulary')}: {exc}") from None
    if control is None:
        return Robot(registry, LEARNER_CONTROL, "new", vocabulary)
    try:
        text = read_at_most(control, DEFAULT_LIMITS.max_size)
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise RobotError(f"{named('control')}: cannot read {control}: {reason}") from None
    try:
        tree = parse(text)
        problems = find_problems(tree, registry)
        if problems:
            raise problems[0]
    except StringBTError as err:
        where = f":{err.line}:{err.column}" if err.line else ""
        raise RobotError(f"{named('control')} {control}{where}: {err.code} {err.message}") from None
    slot = learning_slot(tree)
    if slot is None:
        raise RobotError(
            f"{named('control')} {control}: no <k>(...) placeholder, so nothing learned could "
            "ever run; add one where learned skills belong, e.g. <sl><k>(new)<e>...<e>"
        )
    return Robot(registry, text.decode("utf-8"), slot, vocabulary)
