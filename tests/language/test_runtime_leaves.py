"""Runtime behaviour of the leaves (spec sections 3.2, 3.3 and 3.4) and what a LiveTree refuses
(section 5, registry rules).

Conditions and actions are registered on a plain ``kp.Registry`` here, so the registry's own
calling conventions (blackboard first, keyword arguments, ``halt=`` hooks, action classes) are
what is under test.
"""

from __future__ import annotations

from typing import Any

import pytest

import ktbt_proto as kp
from ktbt_proto.errors import ErrorCode
from ktbt_proto.status import Status
from tests.runtime_helpers import F, FakeClock, Harness, R, S

# -- conditions --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("value", "plain", "negated"),
    [(True, S, F), (False, F, S), (None, F, S), (1, S, F), (0, F, S), ("yes", S, F)],
)
def test_flag_conditions_and_negation(value: object, plain: Status, negated: Status) -> None:
    reg = kp.Registry()
    reg.flags("X")
    bb = kp.Blackboard()
    if value is not None:  # None: the flag is missing, which reads as false
        bb["X"] = value
    assert kp.LiveTree("<c>(X)", reg, bb).tick() is plain
    assert kp.LiveTree("<c>X", reg, bb).tick() is plain
    assert kp.LiveTree("<c>(!X)", reg, bb).tick() is negated
    assert kp.LiveTree("<c>!X", reg, bb).tick() is negated


def test_flag_condition_reads_the_blackboard_on_every_tick() -> None:
    reg = kp.Registry()
    reg.flags("X")
    live = kp.LiveTree("<c>(!X)", reg)
    assert isinstance(live.blackboard, kp.Blackboard)
    assert live.tick() is S
    live.blackboard["X"] = True
    assert live.tick() is F
    del live.blackboard["X"]
    assert live.tick() is S


def test_condition_receives_the_blackboard_and_its_keyword_arguments() -> None:
    reg = kp.Registry()
    calls: list[tuple[Any, dict[str, Any]]] = []

    @reg.condition("Near")
    def near(bb: Any, dist: float, frame: str = "map", strict: bool = False) -> bool:
        calls.append((bb, {"dist": dist, "frame": frame, "strict": strict}))
        return bool(bb["range"] <= dist)

    bb = kp.Blackboard(range=2)
    live = kp.LiveTree('<sq><c>(Near, dist=2.5, frame="odom", strict=true)<e>', reg, bb)
    assert live.tick() is S
    bb["range"] = 3
    assert live.tick() is F
    assert len(calls) == 2
    for passed, args in calls:
        assert passed is bb
        assert args == {"dist": 2.5, "frame": "odom", "strict": True}
        assert type(args["dist"]) is float and type(args["strict"]) is bool

    calls.clear()
    negated = kp.LiveTree("<c>(!Near, dist=3)", reg, bb)
    assert negated.tick() is F
    bb["range"] = 4
    assert negated.tick() is S
    assert [args for _, args in calls] == [{"dist": 3, "frame": "map", "strict": False}] * 2
    assert type(calls[0][1]["dist"]) is int


@pytest.mark.parametrize("answer", [kp.RUNNING, kp.SUCCESS, kp.FAILURE, True, False, 1, 0, None])
def test_a_condition_never_returns_running(answer: object) -> None:
    reg = kp.Registry()

    @reg.condition("Odd")
    def odd(bb: Any) -> object:
        return answer

    for text in ("<c>(Odd)", "<c>(!Odd)"):
        live = kp.LiveTree(text, reg)
        for _ in range(3):
            assert live.tick() in (S, F), text


def test_a_condition_is_never_halted_and_guards_nothing_after_it() -> None:
    h = Harness()
    h.condition("X")
    h.bb["X"] = True
    live = h.live("<sq><c>(X)<c>(!X)<e>")
    assert h.tick(live) == (F, ["X?", "X?"])
    assert h.halt(live) == []


# -- actions: what they return -----------------------------------------------------------------


@pytest.mark.parametrize(
    ("value", "expected"),
    [(S, S), (F, F), (R, R), (True, S), (None, S), (False, F)],
)
def test_action_return_values(value: object, expected: Status) -> None:
    reg = kp.Registry()

    @reg.action("Act")
    def act(bb: Any) -> object:
        return value

    assert kp.LiveTree("<a>(Act)", reg).tick() is expected
    assert kp.LiveTree("<a>Act", reg).tick() is expected


@pytest.mark.parametrize("value", [1, 0, 1.0, "SUCCESS", "RUNNING", [], object()])
def test_action_returning_a_non_status_raises_type_error_naming_it(value: object) -> None:
    reg = kp.Registry()

    @reg.action("BadAction")
    def bad(bb: Any) -> object:
        return value

    live = kp.LiveTree("<sq><a>(BadAction)<e>", reg)
    with pytest.raises(TypeError, match="BadAction"):
        live.tick()


def test_action_class_returning_a_non_status_raises_type_error_naming_it() -> None:
    reg = kp.Registry()

    @reg.action("Weird")
    class Weird:
        def __init__(self, bb: Any) -> None:
            pass

        def tick(self) -> object:
            return "done"

    with pytest.raises(TypeError, match="Weird"):
        kp.LiveTree("<a>(Weird)", reg).tick()


# -- action classes ----------------------------------------------------------------------------


class Steps:
    """RUNNING for ``n`` ticks, then SUCCESS (and starts over). Logs ``tag:count`` on each tick
    and ``~tag`` on halt into ``bb["log"]``; every instance is recorded in ``bb["made"]``."""

    def __init__(self, bb: Any, tag: str, n: int = 1) -> None:
        self.log: list[str] = bb["log"]
        self.tag = tag
        self.n = n
        self.count = 0
        bb["made"].append(self)

    def tick(self) -> Status:
        self.count += 1
        self.log.append(f"{self.tag}:{self.count}")
        if self.count > self.n:
            self.count = 0
            return S
        return R

    def halt(self) -> None:
        self.log.append(f"~{self.tag}")
        self.count = 0


def steps_setup() -> tuple[kp.Registry, kp.Blackboard, list[str], list[Steps]]:
    reg = kp.Registry()
    reg.add_action("Steps", Steps)
    reg.flags("G")
    log: list[str] = []
    made: list[Steps] = []
    return reg, kp.Blackboard(log=log, made=made), log, made


def ticks(live: kp.LiveTree, log: list[str], n: int) -> list[tuple[Status, list[str]]]:
    out: list[tuple[Status, list[str]]] = []
    for _ in range(n):
        mark = len(log)
        status = live.tick()
        out.append((status, log[mark:]))
    return out


def test_action_class_gets_one_instance_per_node() -> None:
    reg, bb, log, made = steps_setup()
    text = '<msq><a>(Steps, tag="a", n=2)<a>(Steps, tag="b", n=1)<e>'
    live = kp.LiveTree(text, reg, bb)
    assert [(s.tag, s.n) for s in made] == [("a", 2), ("b", 1)]
    assert ticks(live, log, 4) == [
        (R, ["a:1"]),
        (R, ["a:2"]),
        (R, ["a:3", "b:1"]),  # b counts from its own zero
        (S, ["b:2"]),
    ]
    assert len(made) == 2  # no instance is made while ticking


def test_two_nodes_with_the_same_action_and_arguments_keep_separate_state() -> None:
    reg, bb, log, made = steps_setup()
    live = kp.LiveTree('<pl><a>(Steps, tag="x", n=1)<a>(Steps, tag="x", n=1)<e>', reg, bb)
    assert len(made) == 2 and made[0] is not made[1]
    assert ticks(live, log, 2) == [(R, ["x:1", "x:1"]), (S, ["x:2", "x:2"])]


def test_action_class_halt_is_called_only_when_it_was_running() -> None:
    reg, bb, log, _ = steps_setup()
    live = kp.LiveTree('<sq><c>(G)<a>(Steps, tag="a", n=1)<e>', reg, bb)
    assert ticks(live, log, 1) == [(F, [])]  # never ticked: never halted
    live.halt()
    assert log == []
    bb["G"] = True
    assert ticks(live, log, 2) == [(R, ["a:1"]), (S, ["a:2"])]
    bb["G"] = False
    assert ticks(live, log, 1) == [(F, [])]  # it finished by itself: not halted
    bb["G"] = True
    assert ticks(live, log, 1) == [(R, ["a:1"])]
    bb["G"] = False
    assert ticks(live, log, 2) == [(F, ["~a"]), (F, [])]  # halted once
    live.halt()
    assert log[-1] == "~a" and log.count("~a") == 1


def test_live_halt_calls_a_running_action_class_halt_once() -> None:
    reg, bb, log, _ = steps_setup()
    live = kp.LiveTree('<a>(Steps, tag="a", n=5)', reg, bb)
    assert ticks(live, log, 2) == [(R, ["a:1"]), (R, ["a:2"])]
    live.halt()
    live.halt()
    assert log == ["a:1", "a:2", "~a"]
    assert ticks(live, log, 1) == [(R, ["a:1"])]


def test_action_class_without_halt_can_be_preempted() -> None:
    reg = kp.Registry()
    reg.flags("G")

    @reg.action("Forever")
    class Forever:
        def __init__(self, bb: Any) -> None:
            self.ticks = 0

        def tick(self) -> Status:
            self.ticks += 1
            return R

    bb = kp.Blackboard(G=True)
    live = kp.LiveTree("<sq><c>(G)<a>(Forever)<e>", reg, bb)
    assert live.tick() is R
    bb["G"] = False
    assert live.tick() is F
    live.halt()


# -- function actions with a halt hook ---------------------------------------------------------


def test_function_action_halt_hook_gets_the_blackboard_and_arguments() -> None:
    reg = kp.Registry()
    reg.flags("G")
    calls: list[tuple[str, Any, float]] = []
    script = [R, S, R, R]

    def stop(bb: Any, speed: float) -> None:
        calls.append(("halt", bb, speed))

    @reg.action("Move", halt=stop)
    def move(bb: Any, speed: float) -> Status:
        calls.append(("tick", bb, speed))
        return script.pop(0)

    bb = kp.Blackboard(G=True)
    live = kp.LiveTree("<sq><c>(G)<a>(Move, speed=0.5)<e>", reg, bb)
    assert [live.tick() for _ in range(2)] == [R, S]
    bb["G"] = False
    assert live.tick() is F  # Move finished by itself: the hook is not called
    assert [c[0] for c in calls] == ["tick", "tick"]
    bb["G"] = True
    assert live.tick() is R
    bb["G"] = False
    assert live.tick() is F
    assert live.tick() is F
    live.halt()
    assert [c[0] for c in calls] == ["tick", "tick", "tick", "halt"]
    assert all(passed is bb and speed == 0.5 for _, passed, speed in calls)


def test_function_action_without_a_halt_hook_can_be_preempted() -> None:
    reg = kp.Registry()
    reg.flags("G")

    @reg.action("Spin")
    def spin(bb: Any) -> Status:
        return R

    bb = kp.Blackboard(G=True)
    live = kp.LiveTree("<sq><c>(G)<a>(Spin)<e>", reg, bb)
    assert live.tick() is R
    bb["G"] = False
    assert live.tick() is F
    live.halt()


def test_action_keyword_arguments_keep_their_types() -> None:
    reg = kp.Registry()
    seen: list[dict[str, Any]] = []

    @reg.action("Any")
    def anything(bb: Any, **kw: Any) -> None:
        seen.append(kw)

    live = kp.LiveTree('<a>(Any, i=-2, f=1.0, e=2.5e-07, b=false, s="caf\\u00e9")', reg)
    assert live.tick() is S
    assert seen == [{"i": -2, "f": 1.0, "e": 2.5e-07, "b": False, "s": "café"}]
    assert [type(v) for v in seen[0].values()] == [int, float, float, bool, str]


# -- <w>(N): waiting in ticks ------------------------------------------------------------------


@pytest.mark.parametrize("text", ["<w>(2)", "<w>2"])
def test_wait_ticks_runs_n_ticks_then_succeeds_and_restarts(text: str) -> None:
    live = kp.LiveTree(text, kp.Registry())
    assert [live.tick() for _ in range(7)] == [R, R, S, R, R, S, R]


def test_wait_zero_ticks_succeeds_at_once() -> None:
    live = kp.LiveTree("<w>(0)", kp.Registry())
    assert [live.tick() for _ in range(3)] == [S, S, S]


def test_wait_ticks_halt_resets_it() -> None:
    reg = kp.Registry()
    reg.flags("G")
    bb = kp.Blackboard(G=True)
    live = kp.LiveTree("<sq><c>(G)<w>(2)<e>", reg, bb)
    assert live.tick() is R
    bb["G"] = False
    assert live.tick() is F
    bb["G"] = True
    assert [live.tick() for _ in range(3)] == [R, R, S]
    assert live.tick() is R
    live.halt()
    assert [live.tick() for _ in range(3)] == [R, R, S]


# -- <wt>(S): waiting in seconds on an injected clock ------------------------------------------


def wt(text: str, clock: FakeClock, registry: kp.Registry | None = None) -> kp.LiveTree:
    reg = kp.Registry() if registry is None else registry
    return kp.LiveTree(text, reg, kp.Blackboard(), clock=clock)


def run_at(live: kp.LiveTree, clock: FakeClock, times: list[float]) -> list[Status]:
    out: list[Status] = []
    for now in times:
        clock.now = now
        out.append(live.tick())
    return out


def test_wait_seconds_runs_until_the_time_has_passed_then_restarts() -> None:
    clock = FakeClock(10.0)
    live = wt("<wt>(1.5)", clock)
    times = [10.0, 11.0, 11.4375, 11.5, 11.75, 13.0, 13.25, 13.25]
    assert run_at(live, clock, times) == [R, R, R, S, R, R, S, R]


def test_wait_seconds_starts_counting_at_its_first_tick() -> None:
    clock = FakeClock(0.0)
    live = wt("<wt>1.5", clock)
    assert run_at(live, clock, [100.0, 101.25, 101.5]) == [R, R, S]


def test_wait_seconds_integer_and_zero() -> None:
    clock = FakeClock()
    assert run_at(wt("<wt>(2)", clock), clock, [0.0, 1.0, 2.0]) == [R, R, S]
    assert run_at(wt("<wt>(0)", clock), clock, [5.0, 5.0, 6.0]) == [S, S, S]


def test_wait_seconds_halt_restarts_the_time() -> None:
    reg = kp.Registry()
    reg.flags("G")
    clock = FakeClock()
    bb = kp.Blackboard(G=True)
    live = kp.LiveTree("<sq><c>(G)<wt>(2)<e>", reg, bb, clock=clock)
    assert run_at(live, clock, [0.0]) == [R]
    bb["G"] = False
    assert run_at(live, clock, [1.0]) == [F]
    bb["G"] = True
    assert run_at(live, clock, [1.5, 3.0, 3.25, 3.5]) == [R, R, R, S]
    assert run_at(live, clock, [4.0]) == [R]
    live.halt()
    assert run_at(live, clock, [5.0, 6.75, 7.0]) == [R, R, S]


def test_wait_seconds_is_deterministic_under_the_injected_clock() -> None:
    clock = FakeClock()
    results = []
    for _ in range(3):
        live = wt("<msq><wt>(0.5)<w>(1)<e>", clock)
        results.append(run_at(live, clock, [0.0, 0.25, 0.5, 0.5, 0.75, 1.0]))
    assert results == [[R, R, R, S, R, R]] * 3


# -- what a LiveTree refuses -------------------------------------------------------------------


def refusing_registry() -> tuple[kp.Registry, kp.Blackboard]:
    reg = kp.Registry()
    reg.flags("Flag")
    reg.add_action("Steps", Steps)

    @reg.condition("Near")
    def near(bb: Any, dist: float) -> bool:
        return True

    @reg.action("Move")
    def move(bb: Any, speed: float, frame: str = "map") -> Status:
        return S

    return reg, kp.Blackboard(log=[], made=[])


@pytest.mark.parametrize(
    ("text", "code"),
    [
        ("<a>(Teleport)", ErrorCode.UNKNOWN_ACTION),
        ("<sq><c>(Flag)<a>Teleport<e>", ErrorCode.UNKNOWN_ACTION),
        ("<c>(Unknown)", ErrorCode.UNKNOWN_CONDITION),
        ("<sq><c>(!Unknown)<a>(Move, speed=1)<e>", ErrorCode.UNKNOWN_CONDITION),
        ("<a>(Flag)", ErrorCode.UNKNOWN_ACTION),  # a condition is not an action
        ("<c>(Move, speed=1)", ErrorCode.UNKNOWN_CONDITION),  # nor an action a condition
        ("<a>(Move, speed=1, turbo=true)", ErrorCode.INVALID_ARGUMENTS),
        ("<a>(Move)", ErrorCode.INVALID_ARGUMENTS),
        ("<a>Move", ErrorCode.INVALID_ARGUMENTS),
        ('<a>(Move, frame="odom")', ErrorCode.INVALID_ARGUMENTS),
        ("<c>(Near, far=1)", ErrorCode.INVALID_ARGUMENTS),
        ("<c>(!Near)", ErrorCode.INVALID_ARGUMENTS),
        ("<c>(Flag, strict=true)", ErrorCode.INVALID_ARGUMENTS),
        ("<a>(Steps)", ErrorCode.INVALID_ARGUMENTS),
        ('<a>(Steps, tag="a", m=2)', ErrorCode.INVALID_ARGUMENTS),
    ],
)
def test_live_tree_refuses_what_the_registry_cannot_execute(text: str, code: ErrorCode) -> None:
    reg, bb = refusing_registry()
    with pytest.raises(kp.StringBTError) as caught:
        kp.LiveTree(text, reg, bb)
    assert caught.value.code is code
    assert bb["made"] == []


def test_live_tree_refusal_codes_are_the_spec_codes() -> None:
    reg, bb = refusing_registry()
    expected = {"<a>(Teleport)": "SBT306", "<c>(Unknown)": "SBT305", "<a>(Move)": "SBT311"}
    for text, code in expected.items():
        with pytest.raises(kp.StringBTError) as caught:
            kp.LiveTree(text, reg, bb)
        assert caught.value.code == code, text


def test_live_tree_refuses_the_whole_tree_before_making_any_action_instance() -> None:
    reg, bb = refusing_registry()
    text = '<sq><a>(Steps, tag="a")<a>(Move, speed=1)<a>(Teleport)<e>'
    with pytest.raises(kp.StringBTError) as caught:
        kp.LiveTree(text, reg, bb)
    assert caught.value.code is ErrorCode.UNKNOWN_ACTION
    assert bb["made"] == []


def test_live_tree_accepts_what_the_registry_can_execute() -> None:
    reg, bb = refusing_registry()
    text = '<sq><c>(!Flag)<c>(Near, dist=1.5)<a>(Move, speed=1)<a>(Move, speed=2, frame="odom")<e>'
    assert kp.LiveTree(text, reg, bb).tick() is S
    live = kp.LiveTree('<a>(Steps, tag="a", n=1)', reg, bb)
    assert [s.tag for s in bb["made"]] == ["a"]
    assert live.tick() is R
