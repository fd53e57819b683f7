"""The registry: what a robot can execute, and how it checks the arguments it is given
(spec/stringbt.md, section 5). Its file is the tools' (tests/tools/test_vocabulary.py)."""

from __future__ import annotations

from typing import Any

import pytest

import ktbt_proto as kp
from ktbt_proto.status import Status as Outcome
from tests.door_robot import door_registry


def test_copy_is_independent() -> None:
    reg = door_registry()
    other = reg.copy()
    other.declare("action", "Wave", {"times": Any})
    assert other.has_action("Wave") and not reg.has_action("Wave")


def test_an_argument_named_as_the_blackboard_parameter_is_refused_not_given_twice() -> None:
    """A behaviour taking ``**kw`` takes any argument name but its blackboard parameter's: a
    peer's ``<c>(A, bb=1)`` is refused by validation (SBT311), where it would raise at the
    tick; a positional-only blackboard (``bb, /``) leaves the name free."""
    reg = kp.Registry()

    def named(bb: kp.Blackboard, **kw: object) -> bool:
        return True

    def positional(bb: kp.Blackboard, /, **kw: object) -> bool:
        return bool(kw)

    reg.add_condition("A", named)
    reg.add_condition("B", positional)
    problems = kp.find_problems(kp.parse("<c>(A, bb=1)"), reg)
    assert [(p.code.value, p.message) for p in problems] == [
        ("SBT311", "condition 'A' takes no argument 'bb'")
    ]
    assert kp.LiveTree(kp.parse("<c>(B, bb=1)"), reg).tick() is kp.SUCCESS


def test_a_result_annotated_status_is_trusted_however_the_annotation_is_spelled() -> None:
    """``-> Status`` is resolved as Python resolves it (this module's annotations are strings,
    ``from __future__ import annotations``): any spelling of the class is trusted, so a wrong
    result is the tree's TypeError; a name that does not resolve is not, and the result is
    checked (``True`` counts as SUCCESS)."""

    def spelled(bb: kp.Blackboard) -> kp.Status:
        return True  # type: ignore[return-value]

    def aliased(bb: kp.Blackboard) -> Outcome:
        return True  # type: ignore[return-value]

    def unknown(bb: kp.Blackboard) -> NoSuchStatus:  # type: ignore[name-defined]  # noqa: F821
        return True

    reg = kp.Registry()
    for name, fn in (("Spelled", spelled), ("Aliased", aliased), ("Unknown", unknown)):
        reg.add_action(name, fn)
    for trusted in ("Spelled", "Aliased"):
        with pytest.raises(TypeError, match="trusted"):
            kp.LiveTree(kp.parse(f"<a>({trusted})"), reg).tick()
    assert kp.LiveTree(kp.parse("<a>(Unknown)"), reg).tick() is kp.SUCCESS
