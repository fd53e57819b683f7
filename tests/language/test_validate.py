"""Validation rules (SBT301..SBT310), registries, limits and deep programmatic trees."""

from __future__ import annotations

from pathlib import Path

import pytest

import ktbt_proto as kp
from ktbt_proto.errors import ErrorCode
from ktbt_proto.tree import Inverter, Node, Parallel, Placeholder, RunTimer, Value, Wait, WaitTimer
from ktbt_proto.validate import SupportsNames

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

Where = tuple[str, int, int]
"""(code, line, column) of one problem."""


def problems(tree: kp.Tree | Node, registry: SupportsNames | None = None) -> list[Where]:
    return [(p.code.value, p.line, p.column) for p in kp.find_problems(tree, registry)]


def codes_of(text: str, registry: SupportsNames | None = None) -> list[Where]:
    return problems(kp.parse(text), registry)


# SBT301: decorators need exactly one child.


@pytest.mark.parametrize("tag", ["<neg>", "<tt1>(2)", "<tt2>(2)"])
def test_decorator_without_child(tag: str) -> None:
    assert codes_of(f"<sq>\n  <a>(A)\n  {tag}<e>\n<e>") == [("SBT301", 3, 3)]


@pytest.mark.parametrize("tag", ["<neg>", "<tt1>(2)", "<tt2>(2)"])
def test_decorator_with_two_children(tag: str) -> None:
    assert codes_of(f"{tag}\n  <a>(A)\n  <a>(B)\n<e>") == [("SBT301", 1, 1)]


@pytest.mark.parametrize("tag", ["<neg>", "<tt1>(0)", "<tt2>(7)"])
def test_decorator_with_one_child_is_valid(tag: str) -> None:
    assert codes_of(f"{tag}<a>(A)<e>") == []


def test_decorator_arity_message_counts_children() -> None:
    (problem,) = kp.find_problems(kp.parse("<neg><a>(A)<a>(B)<e>"))
    assert problem.code is ErrorCode.DECORATOR_ARITY
    assert "not 2" in problem.message


# SBT302: composites need at least one child; an empty placeholder is fine.


@pytest.mark.parametrize("tag", ["<sq>", "<sl>", "<msq>", "<msl>", "<pl>", "<pl>(1)"])
def test_empty_composite(tag: str) -> None:
    assert codes_of(f"<sl>\n  <a>(A)\n    {tag}<e>\n<e>") == [("SBT302", 3, 5)]


def test_empty_placeholder_is_valid() -> None:
    assert codes_of("<k>(new)<e>") == []
    assert codes_of("<sl>\n  <k>(new)<e>\n  <a>(A)\n<e>") == []


# SBT303: invalid names on programmatically built nodes, at position (0, 0).


@pytest.mark.parametrize(
    "node",
    [
        kp.Action("1bad"),
        kp.Action("a b"),
        kp.Action(""),
        kp.Action("a."),
        kp.Condition("true"),
        kp.Condition("false", negated=True),
        kp.Condition("x-y"),
        kp.Action("ok", args=(("x-y", 1),)),
        kp.Condition("ok", args=(("true", 1),)),
        Placeholder((), name=""),
        Placeholder((kp.Action("A"),), name="new knowledge"),
    ],
    ids=repr,
)
def test_invalid_name(node: Node) -> None:
    assert problems(node) == [("SBT303", 0, 0)]


def test_name_longer_than_literal_limit_is_invalid() -> None:
    limits = kp.Limits(max_literal=8)
    assert kp.find_problems(kp.Action("a" * 8), limits=limits) == []
    (problem,) = kp.find_problems(kp.Action("a" * 9), limits=limits)
    assert (problem.code, problem.line, problem.column) == (ErrorCode.INVALID_NAME, 0, 0)


def test_dotted_names_are_valid() -> None:
    tree = kp.SequenceNode(
        (kp.Condition("robot.sensors.ok", args=(("a_1", 1),)), kp.Action("arm.Grip")),
    )
    assert problems(tree) == []


# SBT304: duplicate placeholder names, reported at the second one.


def test_duplicate_placeholder() -> None:
    text = "<sl>\n  <k>(new)<e>\n  <sq>\n    <a>(A)\n      <k>(new)\n<a>(B)<e>\n  <e>\n<e>"
    assert codes_of(text) == [("SBT304", 5, 7)]


def test_distinct_placeholders_are_valid() -> None:
    assert codes_of("<sl><k>(common)<e><k>(prior)<e><k>(new)<e><e>") == []


def test_three_equal_placeholders_flag_the_second_and_third() -> None:
    text = "<sl>\n<k>(p)<e>\n<k>(p)<e>\n<k>(p)<e>\n<e>"
    assert codes_of(text) == [("SBT304", 3, 1), ("SBT304", 4, 1)]


# SBT305 / SBT306: registry checks.

VOCAB = kp.Vocabulary.of(conditions=["Seen"], actions=["Go", "Stop"])


def test_unknown_condition() -> None:
    assert codes_of("<sq>\n  <c>(Seen)\n  <c>(!Heard)\n  <a>(Go)\n<e>", VOCAB) == [("SBT305", 3, 3)]


def test_unknown_action() -> None:
    assert codes_of("<sq>\n  <c>(Seen)\n  <a>(Fly, h=3)\n<e>", VOCAB) == [("SBT306", 3, 3)]


def test_condition_and_action_namespaces_are_separate() -> None:
    # "Go" is an action, not a condition; "Seen" is a condition, not an action.
    assert codes_of("<sq><c>(Go)<a>(Seen)<e>", VOCAB) == [("SBT305", 1, 5), ("SBT306", 1, 12)]


def test_known_names_pass() -> None:
    assert codes_of("<sl><sq><c>(!Seen)<a>(Go)<e><a>(Stop)<e>", VOCAB) == []


def test_no_registry_means_no_registry_checks() -> None:
    assert codes_of("<sq><c>(Anything)<a>(Whatever)<e>") == []


def test_invalid_name_is_not_also_reported_as_unknown() -> None:
    assert problems(kp.Action("1bad"), VOCAB) == [("SBT303", 0, 0)]


# SBT307: tick counts and durations.


@pytest.mark.parametrize(
    ("text", "where"),
    [
        ("<w>(1.5)", ("SBT307", 1, 1)),
        ("<w>(-1)", ("SBT307", 1, 1)),
        ("<w>(1e3)", ("SBT307", 1, 1)),
        ("<wt>(-0.5)", ("SBT307", 1, 1)),
        ("<sq>\n  <a>(A)\n  <tt1>(-3)<a>(B)<e>\n<e>", ("SBT307", 3, 3)),
        ("<tt2>(2.5)<a>(B)<e>", ("SBT307", 1, 1)),
    ],
)
def test_invalid_duration(text: str, where: Where) -> None:
    assert codes_of(text) == [where]


@pytest.mark.parametrize("text", ["<w>(0)", "<w>(3)", "<wt>(0.5)", "<wt>(0)", "<wt>(2)"])
def test_valid_duration(text: str) -> None:
    assert codes_of(text) == []


@pytest.mark.parametrize(
    "node",
    [
        Wait(float("inf"), "seconds"),
        Wait(float("nan"), "seconds"),
        Wait(True, "ticks"),
        Wait(True, "seconds"),
        Wait(1, "minutes"),  # type: ignore[arg-type]
        Wait("1", "seconds"),  # type: ignore[arg-type]
        WaitTimer((kp.Action("A"),), ticks=True),
        RunTimer((kp.Action("A"),), ticks=-1),
    ],
    ids=repr,
)
def test_invalid_duration_on_programmatic_node(node: Node) -> None:
    assert problems(node) == [("SBT307", 0, 0)]


def test_huge_integer_seconds_are_checked_without_crashing() -> None:
    # 400 digits is within the literal limit; an integer too large for a float is still finite.
    assert kp.find_problems(kp.parse("<wt>(" + "9" * 400 + ")")) == []
    assert problems(Wait(-(10**400), "seconds")) == [("SBT307", 0, 0)]


def test_unhashable_names_are_problems_not_crashes() -> None:
    bad = kp.SequenceNode((kp.Action(["x"]), Placeholder((), name=["y"])))  # type: ignore[arg-type]
    assert [p.code.value for p in kp.find_problems(bad)] == ["SBT303", "SBT303"]


def test_a_limit_problem_is_raised_before_rule_problems() -> None:
    tree = kp.SequenceNode((Inverter(()), kp.SequenceNode((kp.SequenceNode((kp.Action("A"),)),))))
    with pytest.raises(kp.LimitError) as info:
        kp.validate(tree, limits=kp.Limits(max_depth=2))
    assert info.value.code is ErrorCode.TOO_DEEP


# SBT308: parallel threshold.


@pytest.mark.parametrize(
    ("text", "where"),
    [
        ("<pl>(0)\n  <a>(A)\n<e>", ("SBT308", 1, 1)),
        ("<pl>(3)\n  <a>(A)\n  <a>(B)\n<e>", ("SBT308", 1, 1)),
        ("<pl>(1.5)\n  <a>(A)\n  <a>(B)\n<e>", ("SBT308", 1, 1)),
        ("<pl>(-1)\n  <a>(A)\n<e>", ("SBT308", 1, 1)),
        ("<sq>\n  <a>(A)\n  <pl>(2)<a>(B)<e>\n<e>", ("SBT308", 3, 3)),
    ],
)
def test_invalid_threshold(text: str, where: Where) -> None:
    assert codes_of(text) == [where]


@pytest.mark.parametrize(
    "text",
    ["<pl>(2)<a>(A)<a>(B)<e>", "<pl>(1)<a>(A)<a>(B)<e>", "<pl><a>(A)<a>(B)<e>"],
)
def test_valid_threshold(text: str) -> None:
    assert codes_of(text) == []


def test_bool_threshold_is_invalid() -> None:
    node = Parallel((kp.Action("A"),), threshold=True)
    assert problems(node) == [("SBT308", 0, 0)]


# SBT309: duplicate argument.


def test_duplicate_argument() -> None:
    assert codes_of("<sq>\n  <a>(X, y=1, y=2)\n<e>") == [("SBT309", 2, 3)]


def test_duplicate_argument_on_condition() -> None:
    assert codes_of('<c>(!X, y="a", z=1, y="a")') == [("SBT309", 1, 1)]


def test_distinct_arguments_are_valid() -> None:
    assert codes_of('<a>(X, y=1, z=2.5, s="t", b=true)') == []


# SBT310: invalid argument values on programmatic nodes.


@pytest.mark.parametrize(
    "value",
    [float("nan"), float("inf"), float("-inf"), [1, 2], None, b"x", "\ud800", "a\udfffb"],
    ids=repr,
)
def test_invalid_value(value: object) -> None:
    node = kp.Action("A", args=(("x", value),))  # type: ignore[arg-type]
    assert problems(node) == [("SBT310", 0, 0)]


@pytest.mark.parametrize("value", [0, -7, 10**30, 1.5, -0.0, "", "ü✓", True, False], ids=repr)
def test_valid_value(value: Value) -> None:
    assert problems(kp.Condition("C", args=(("x", value),))) == []


def test_every_argument_problem_is_reported_in_order() -> None:
    node = kp.Action(
        "A",
        args=(("x", float("nan")), ("y", [1]), ("z", "\ud800"), ("x-y", 1), ("y", 2)),  # type: ignore[arg-type]
    )
    assert [p.code for p in kp.find_problems(node)] == [
        ErrorCode.INVALID_VALUE,
        ErrorCode.INVALID_VALUE,
        ErrorCode.INVALID_VALUE,
        ErrorCode.INVALID_NAME,
        ErrorCode.DUPLICATE_ARGUMENT,
    ]


def test_non_node_is_rejected() -> None:
    assert problems(kp.SequenceNode((Node(),))) == [("SBT310", 0, 0)]


# validate.


def test_validate_raises_first_problem_with_all_problems() -> None:
    text = "<sl>\n  <neg><e>\n  <sq><e>\n  <a>(X, y=1, y=2)\n  <w>(-1)\n  <pl>(5)<a>(A)<e>\n<e>"
    tree = kp.parse(text)
    with pytest.raises(kp.ValidationError) as info:
        kp.validate(tree)
    error = info.value
    assert (error.code, error.line, error.column) == (ErrorCode.DECORATOR_ARITY, 2, 3)
    assert [(p.code.value, p.line, p.column) for p in error.problems] == [
        ("SBT301", 2, 3),
        ("SBT302", 3, 3),
        ("SBT309", 4, 3),
        ("SBT307", 5, 3),
        ("SBT308", 6, 3),
    ]
    assert error.problems[0] is error
    assert [(p.code, p.line, p.column) for p in error.problems] == [
        (p.code, p.line, p.column) for p in kp.find_problems(tree)
    ]


def test_validate_with_registry() -> None:
    with pytest.raises(kp.ValidationError) as info:
        kp.validate(kp.parse("<sq>\n  <c>(Seen)\n  <a>(Fly)\n<e>"), VOCAB)
    assert (info.value.code, info.value.line, info.value.column) == (ErrorCode.UNKNOWN_ACTION, 3, 3)
    assert len(info.value.problems) == 1


def test_validate_returns_none_for_valid_tree() -> None:
    tree = kp.parse((EXAMPLES / "sar_control.sbt").read_text(encoding="utf-8"))
    assert kp.find_problems(tree) == []
    assert kp.validate(tree) is None  # type: ignore[func-returns-value]
    assert kp.validate(tree.root) is None  # type: ignore[func-returns-value]


# Limits.


def chain(depth: int) -> Node:
    """Inverters nested ``depth - 1`` deep around one action: ``depth`` levels in all."""
    node: Node = kp.Action("A")
    for _ in range(depth - 1):
        node = Inverter((node,))
    return node


def test_depth_limit() -> None:
    limits = kp.Limits(max_depth=3)
    assert kp.find_problems(chain(3), limits=limits) == []
    with pytest.raises(kp.LimitError) as info:
        kp.validate(chain(4), limits=limits)
    assert not isinstance(info.value, kp.ValidationError)
    assert (info.value.code, info.value.line, info.value.column) == (ErrorCode.TOO_DEEP, 0, 0)


def test_node_limit() -> None:
    limits = kp.Limits(max_nodes=5)
    five = kp.SequenceNode(tuple(kp.Action(f"A{i}") for i in range(4)))
    six = kp.SequenceNode(tuple(kp.Action(f"A{i}") for i in range(5)))
    assert kp.find_problems(five, limits=limits) == []
    with pytest.raises(kp.LimitError) as info:
        kp.validate(six, limits=limits)
    assert (info.value.code, info.value.line, info.value.column) == (
        ErrorCode.TOO_MANY_NODES,
        0,
        0,
    )


def test_limit_from_parsed_tree_has_position() -> None:
    tree = kp.parse("<sq>\n  <neg>\n    <neg>\n      <a>(A)\n    <e>\n  <e>\n<e>")
    (problem,) = kp.find_problems(tree, limits=kp.Limits(max_depth=3))
    assert isinstance(problem, kp.LimitError)
    assert (problem.code.value, problem.line, problem.column) == ("SBT202", 4, 7)


def test_check_stops_at_first_limit_problem() -> None:
    # Every action has an invalid name: only those before the limit are reported.
    tree = kp.SequenceNode(tuple(kp.Action(f"{i}bad") for i in range(10)))
    found = kp.find_problems(tree, limits=kp.Limits(max_nodes=3))
    assert [p.code for p in found] == [
        ErrorCode.INVALID_NAME,
        ErrorCode.INVALID_NAME,
        ErrorCode.TOO_MANY_NODES,
    ]
    assert isinstance(found[-1], kp.LimitError)

    deep = kp.SequenceNode((chain(10), kp.Action("1bad"), kp.Action("2bad")))
    found = kp.find_problems(deep, limits=kp.Limits(max_depth=4))
    assert [p.code for p in found] == [ErrorCode.TOO_DEEP]


def test_very_deep_programmatic_tree() -> None:
    tree = chain(50_000)
    limits = kp.Limits(max_depth=60_000)
    assert kp.find_problems(tree, limits=limits) == []
    assert kp.validate(tree, limits=limits) is None  # type: ignore[func-returns-value]
    with pytest.raises(kp.LimitError) as info:
        kp.validate(tree)
    assert info.value.code is ErrorCode.TOO_DEEP
