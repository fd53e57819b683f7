"""Tick rate, build time and hot-merge time of the live runtime, against py_trees in the same run.

Run with ``python -m benchmarks.bench_runtime`` (or ``python -m benchmarks`` for every module).
Prints Markdown tables and writes the numbers to ``benchmarks/results/runtime.json``.

Three contenders tick the 51-node reference tree (a reactive Selector over 10 Sequences of two
conditions and two actions), all calling the same 40 leaf functions where they call any:

* ours: ``LiveTree.tick()`` on the tree compiled from stringBT;
* py_trees: ``BehaviourTree.tick()`` with ``memory=False`` composites and minimal behaviours whose
  ``update()`` returns a fixed status (the most favourable setup for py_trees);
* a flat, hand-written Python loop over the leaf functions: the practical ceiling for a tree
  interpreted in Python.

"Full traversal" scripts the leaves so that every node ticks on every tick (each Sequence fails on
its last action, the last one is RUNNING); "early exit" lets the first Sequence succeed.

Hot merge: the search-and-rescue control tree of ``examples/sar_control.sbt``, already
running,
learns a 5-node knowledge item ``Sequence(TargetSeen, Sequence(PickTreasure,
AssignCollectionPoint))`` into its ``new`` placeholder; the time covers the merge and the first
tick after it (the one that applies the merge and runs the new knowledge). The anchor is
py_trees' ``insert_subtree`` of the same 5 behaviours into a py_trees copy of that tree, plus one
tick. Every sample gets a fresh tree (built outside the timed region) and a new colour.
"""

from __future__ import annotations

import argparse
import gc
import importlib.metadata
import itertools
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, TypeVar

import py_trees
from py_trees.behaviour import Behaviour
from py_trees.common import Status as PtStatus
from py_trees.composites import Selector as PtSelector
from py_trees.composites import Sequence as PtSequence
from py_trees.trees import BehaviourTree

import ktbt_proto as kp
from ktbt_proto.syntax import _lark

from .timing import Stats, gc_paused, interleaved, machine, markdown_table, write_json

BRANCHES = 10
"""Sequences under the reference tree's root Selector."""
FAST_BATCH = 200
"""Ticks per sample for ours and the flat loop."""
PY_TREES_BATCH = {"full": 5, "early": 50}
"""Ticks per sample for py_trees, per scenario (it is much slower per tick)."""
TICK_ROUNDS = 800
"""Interleaved rounds of the tick benchmark (each times every contender and scenario once)."""
BUILD_ROUNDS = 600
"""Interleaved rounds of the build benchmark."""
MERGE_ROUNDS = 1500
"""Rounds of the hot-merge benchmark (each times every variant once on fresh trees)."""
SAR_PATH = Path(__file__).resolve().parents[1] / "examples" / "sar_control.sbt"
SCENARIOS = ("full", "early")
CONTENDERS = ("ours", "py_trees", "flat")

TARGET_TICK_RATIO = 50.0
TARGET_BUILD_US = 100.0
TARGET_MERGE_US = 50.0

SUCCESS, FAILURE, RUNNING = kp.SUCCESS, kp.FAILURE, kp.RUNNING
TO_PY_TREES: dict[kp.Status, PtStatus] = {
    SUCCESS: PtStatus.SUCCESS,
    FAILURE: PtStatus.FAILURE,
    RUNNING: PtStatus.RUNNING,
}

T = TypeVar("T")
Cond = Callable[[Any], bool]
"""A condition leaf: ``predicate(bb) -> bool``."""
Act = Callable[[Any], kp.Status]
"""An action leaf: ``action(bb) -> kp.Status``."""
Branch = tuple[Cond, Cond, Act, Act]
"""The leaves of one Sequence: condition a, condition b, action a, action b."""


# -- the reference tree -------------------------------------------------------------------------


def reference_text() -> str:
    """The 51-node reference tree in compact stringBT."""
    body = "".join(
        f"<sq><c>(Cond{i}a)<c>(Cond{i}b)<a>(Act{i}a)<a>(Act{i}b)<e>" for i in range(BRANCHES)
    )
    return f"<sl>{body}<e>"


def _constant(value: T) -> Callable[[Any], T]:
    """A distinct leaf function that ignores the blackboard and returns ``value``."""

    def leaf(bb: Any) -> T:
        return value

    return leaf


@dataclass(frozen=True)
class Script:
    """One scenario: the leaf functions of every branch, in tree order."""

    name: str
    branches: tuple[Branch, ...]
    """The leaves of each Sequence."""
    statuses: tuple[tuple[bool, bool, kp.Status, kp.Status], ...]
    """What those leaves return, for building the py_trees twin."""
    expected: kp.Status
    """The root's status on every tick."""
    nodes_ticked: int
    """Nodes (composites included) ticked on every tick."""
    leaves_ticked: int
    """Leaf functions called on every tick."""

    def registry(self) -> kp.Registry:
        reg = kp.Registry()
        for i, (ca, cb, aa, ab) in enumerate(self.branches):
            reg.add_condition(f"Cond{i}a", ca)
            reg.add_condition(f"Cond{i}b", cb)
            reg.add_action(f"Act{i}a", aa)
            reg.add_action(f"Act{i}b", ab)
        return reg


def script(name: str) -> Script:
    """``full``: every condition true, action a SUCCESS, action b FAILURE except the last branch's
    (RUNNING), so every node ticks. ``early``: the first branch succeeds, so only it ticks."""
    statuses: list[tuple[bool, bool, kp.Status, kp.Status]] = []
    for i in range(BRANCHES):
        last = FAILURE
        if name == "full" and i == BRANCHES - 1:
            last = RUNNING
        elif name == "early" and i == 0:
            last = SUCCESS
        statuses.append((True, True, SUCCESS, last))
    branches = tuple(
        (_constant(ca), _constant(cb), _constant(aa), _constant(ab)) for ca, cb, aa, ab in statuses
    )
    if name == "full":
        return Script(name, branches, tuple(statuses), RUNNING, 1 + 5 * BRANCHES, 4 * BRANCHES)
    return Script(name, branches, tuple(statuses), SUCCESS, 1 + 5, 4)


def flat_ticker(branches: Sequence[Branch], bb: Any) -> Callable[[], kp.Status]:
    """The reference tree written by hand as one loop: the practical ceiling."""
    table = tuple(branches)

    def tick() -> kp.Status:
        for ca, cb, aa, ab in table:
            if ca(bb) and cb(bb):
                status = aa(bb)
                if status is SUCCESS:
                    status = ab(bb)
                if status is not FAILURE:
                    return status
        return FAILURE

    return tick


class _Fixed(Behaviour):
    """A minimal py_trees leaf: ``update()`` returns a fixed status."""

    def __init__(self, name: str, status: PtStatus) -> None:
        super().__init__(name)
        self.result = status

    def update(self) -> PtStatus:
        return self.result


def py_trees_reference(s: Script) -> BehaviourTree:
    """The reference tree in py_trees: reactive (``memory=False``) composites, fixed leaves."""

    def cond(name: str, holds: bool) -> _Fixed:
        return _Fixed(name, PtStatus.SUCCESS if holds else PtStatus.FAILURE)

    branches = [
        PtSequence(
            f"Branch{i}",
            memory=False,
            children=[
                cond(f"Cond{i}a", ca),
                cond(f"Cond{i}b", cb),
                _Fixed(f"Act{i}a", TO_PY_TREES[aa]),
                _Fixed(f"Act{i}b", TO_PY_TREES[ab]),
            ],
        )
        for i, (ca, cb, aa, ab) in enumerate(s.statuses)
    ]
    return BehaviourTree(PtSelector("Root", memory=False, children=branches))


def _batch(tick: Callable[[], object], n: int) -> Callable[[], None]:
    repeat = itertools.repeat

    def run() -> None:
        for _ in repeat(None, n):
            tick()

    return run


def _check_reference(s: Script, text: str) -> None:
    """Each contender returns the scripted status and ticks the scripted number of nodes."""
    calls = 0

    def counting(leaf: Callable[[Any], T]) -> Callable[[Any], T]:
        def counted(bb: Any) -> T:
            nonlocal calls
            calls += 1
            return leaf(bb)

        return counted

    counted = replace(
        s,
        branches=tuple(
            (counting(ca), counting(cb), counting(aa), counting(ab))
            for ca, cb, aa, ab in s.branches
        ),
    )
    leaves = s.leaves_ticked
    live = kp.LiveTree(text, counted.registry())
    flat = flat_ticker(counted.branches, kp.Blackboard())
    for tick in (live.tick, flat):
        for _ in range(2):
            calls = 0
            if tick() is not s.expected or calls != leaves:
                raise AssertionError(f"{s.name}: {tick} ticked {calls} leaves, expected {leaves}")
    bt = py_trees_reference(s)
    for _ in range(2):
        ticked = sum(1 for _ in bt.root.tick())
        if bt.root.status is not TO_PY_TREES[s.expected] or ticked != s.nodes_ticked:
            raise AssertionError(f"{s.name}: py_trees ticked {ticked} nodes, {bt.root.status}")


def run_ticks(rounds: int) -> dict[str, dict[str, Any]]:
    text = reference_text()
    cases: dict[str, Callable[[], object]] = {}
    batches: dict[str, int] = {}
    for name in SCENARIOS:
        s = script(name)
        _check_reference(s, text)
        live = kp.LiveTree(text, s.registry())
        bt = py_trees_reference(s)
        flat = flat_ticker(s.branches, kp.Blackboard())
        for contender, tick, n in (
            ("ours", live.tick, FAST_BATCH),
            ("py_trees", bt.tick, PY_TREES_BATCH[name]),
            ("flat", flat, FAST_BATCH),
        ):
            cases[f"{name}/{contender}"] = _batch(tick, n)
            batches[f"{name}/{contender}"] = n
    stats = interleaved(cases, rounds=rounds, warmup=5)
    out: dict[str, dict[str, Any]] = {}
    for name in SCENARIOS:
        per_tick = {c: stats[f"{name}/{c}"].median_ns / batches[f"{name}/{c}"] for c in CONTENDERS}
        out[name] = {
            "nodes_ticked": script(name).nodes_ticked,
            **{
                c: {
                    "batch": batches[f"{name}/{c}"],
                    "us_per_tick": round(per_tick[c] / 1_000, 3),
                    "p90_us_per_tick": round(
                        stats[f"{name}/{c}"].p90_ns / batches[f"{name}/{c}"] / 1_000, 3
                    ),
                    "ticks_per_s": round(1e9 / per_tick[c]),
                    "over_py_trees": round(per_tick["py_trees"] / per_tick[c], 2),
                }
                for c in CONTENDERS
            },
        }
    return out


# -- building from text ------------------------------------------------------------------------


def run_build(rounds: int) -> dict[str, Any]:
    text = reference_text()
    reg = script("full").registry()
    lark_parser = _lark()  # built (and cached) here, outside any timing
    stats = interleaved(
        {
            "livetree": lambda: kp.LiveTree(text, reg),
            "parse": lambda: kp.parse(text),
            "parse_validate": lambda: kp.validate(kp.parse(text), reg),
            "lark": lambda: lark_parser.parse(text),
        },
        rounds=rounds,
    )
    return {name: _us_stats(st) for name, st in stats.items()}


def _us_stats(st: Stats) -> dict[str, float]:
    return {"median": round(st.median_us, 1), "p90": round(st.p90_us, 1)}


# -- hot merge ---------------------------------------------------------------------------------

SAR_FLAGS = ("_collisionDetectedF", "_waitF", "_treasureOnBoardF", "_inZoneF")
SAR_ACTIONS: dict[str, kp.Status] = {
    "CollisionAvoidance": RUNNING,
    "StopWalk": RUNNING,
    "PlaceTreasure": SUCCESS,
    "WalkToCollection": RUNNING,
    "PickTreasure": SUCCESS,
    "AssignCollectionPoint": SUCCESS,
    "RandomWalk": RUNNING,
}


def sar_vocabulary() -> kp.Registry:
    reg = kp.Registry()
    reg.flags(*SAR_FLAGS)

    @reg.condition("TargetSeen")
    def target_seen(bb: Any, colour: int) -> bool:
        return bool(bb.get("target") == colour)

    for name, status in SAR_ACTIONS.items():
        if name == "AssignCollectionPoint":

            def assign(bb: Any, colour: int, status: kp.Status = status) -> kp.Status:
                return status

            reg.add_action(name, assign)
        else:
            reg.add_action(name, _constant(status))
    return reg


class _PtFlag(Behaviour):
    """A py_trees condition on a blackboard flag (missing = false), optionally negated."""

    def __init__(self, bb: dict[str, Any], key: str, negated: bool = False) -> None:
        super().__init__(("!" if negated else "") + key)
        self.bb, self.key, self.negated = bb, key, negated

    def update(self) -> PtStatus:
        holds = bool(self.bb.get(self.key, False)) != self.negated
        return PtStatus.SUCCESS if holds else PtStatus.FAILURE


class _PtTargetSeen(Behaviour):
    def __init__(self, bb: dict[str, Any], colour: int) -> None:
        super().__init__(f"TargetSeen{colour}")
        self.bb, self.colour = bb, colour

    def update(self) -> PtStatus:
        return PtStatus.SUCCESS if self.bb.get("target") == self.colour else PtStatus.FAILURE


def _pt_action(name: str) -> _Fixed:
    return _Fixed(name, TO_PY_TREES[SAR_ACTIONS[name]])


def _pt_seq(name: str, *children: Behaviour) -> PtSequence:
    return PtSequence(name, memory=False, children=list(children))


def _pt_sel(name: str, *children: Behaviour) -> PtSelector:
    return PtSelector(name, memory=False, children=list(children))


def py_trees_sar(bb: dict[str, Any]) -> tuple[BehaviourTree, PtSelector]:
    """``examples/sar_control.sbt`` in py_trees (placeholders as reactive Selectors);
    returns the tree and its ``new`` placeholder."""
    new = _pt_sel("new")
    root = _pt_sel(
        "Root",
        _pt_seq("Collision", _PtFlag(bb, "_collisionDetectedF"), _pt_action("CollisionAvoidance")),
        _pt_seq("Wait", _PtFlag(bb, "_waitF"), _pt_action("StopWalk")),
        _pt_sel(
            "common",
            _pt_seq(
                "Carry",
                _PtFlag(bb, "_treasureOnBoardF"),
                _pt_sel(
                    "Zone",
                    _pt_seq("Place", _PtFlag(bb, "_inZoneF"), _pt_action("PlaceTreasure")),
                    _pt_seq("Walk", _PtFlag(bb, "_inZoneF", True), _pt_action("WalkToCollection")),
                ),
            ),
        ),
        _pt_sel(
            "prior",
            _pt_seq(
                "Rescue1",
                _PtTargetSeen(bb, 1),
                _pt_action("PickTreasure"),
                _pt_action("AssignCollectionPoint"),
            ),
        ),
        new,
        _pt_action("RandomWalk"),
    )
    return BehaviourTree(root), new


def py_trees_learned(bb: dict[str, Any], colour: int) -> PtSequence:
    """The 5-node knowledge item, as py_trees behaviours."""
    skill = _pt_seq("Skill", _pt_action("PickTreasure"), _pt_action("AssignCollectionPoint"))
    return _pt_seq(f"Learned{colour}", _PtTargetSeen(bb, colour), skill)


def learned_text(colour: int) -> str:
    return f"<sq><a>(PickTreasure)<a>(AssignCollectionPoint, colour={colour})<e>"


@dataclass
class _MergeRound:
    """Everything one round of the merge benchmark needs, prepared outside the timed region."""

    text: str
    when: list[str]
    parsed: kp.Tree
    parsed_when: list[kp.Condition]
    live_text: kp.LiveTree
    live_parsed: kp.LiveTree
    bt_build: BehaviourTree
    new_build: PtSelector
    bb_build: dict[str, Any]
    colour: int
    bt_pre: BehaviourTree
    new_pre: PtSelector
    prebuilt: PtSequence


Timed = tuple[int, bool]
"""Nanoseconds of one timed region, and whether the merge took effect."""


def _ours_text(p: _MergeRound) -> Timed:
    live, text, when, clock = p.live_text, p.text, p.when, time.perf_counter_ns
    start = clock()
    live.merge(text, slot="new", when=when)
    status = live.tick()
    return clock() - start, status is SUCCESS


def _ours_parsed(p: _MergeRound) -> Timed:
    live, parsed, when, clock = p.live_parsed, p.parsed, p.parsed_when, time.perf_counter_ns
    start = clock()
    live.merge(parsed, slot="new", when=when)
    status = live.tick()
    return clock() - start, status is SUCCESS


def _py_trees_build(p: _MergeRound) -> Timed:
    bt, new, bb, colour, clock = p.bt_build, p.new_build, p.bb_build, p.colour, time.perf_counter_ns
    start = clock()
    bt.insert_subtree(py_trees_learned(bb, colour), new.id, len(new.children))
    bt.tick()
    elapsed = clock() - start
    return elapsed, bt.root.status is PtStatus.SUCCESS


def _py_trees_prebuilt(p: _MergeRound) -> Timed:
    bt, new, subtree, clock = p.bt_pre, p.new_pre, p.prebuilt, time.perf_counter_ns
    start = clock()
    bt.insert_subtree(subtree, new.id, len(new.children))
    bt.tick()
    elapsed = clock() - start
    return elapsed, bt.root.status is PtStatus.SUCCESS


MERGE_VARIANTS: dict[str, Callable[[_MergeRound], Timed]] = {
    "ours_text": _ours_text,
    "ours_parsed": _ours_parsed,
    "py_trees_build": _py_trees_build,
    "py_trees_prebuilt": _py_trees_prebuilt,
}


def run_merge(rounds: int, warmup: int = 20) -> dict[str, Any]:
    """Time merge + first tick on fresh, already running trees; a new colour every round."""
    sar = kp.parse(SAR_PATH.read_text(encoding="utf-8"))
    reg = sar_vocabulary()

    def ours_running(colour: int) -> kp.LiveTree:
        live = kp.LiveTree(sar, reg, kp.Blackboard(target=colour))
        if live.tick() is not RUNNING:  # RandomWalk runs: nothing known about this colour
            raise AssertionError("the SAR tree should be running its fallback")
        return live

    def py_trees_running(colour: int) -> tuple[BehaviourTree, PtSelector, dict[str, Any]]:
        bb: dict[str, Any] = {"target": colour}
        bt, new = py_trees_sar(bb)
        bt.tick()
        if bt.root.status is not PtStatus.RUNNING:
            raise AssertionError("the py_trees SAR tree should be running its fallback")
        return bt, new, bb

    def prepare(colour: int) -> _MergeRound:
        text, when = learned_text(colour), [f"TargetSeen(colour={colour})"]
        parsed_when = [kp.Condition("TargetSeen", args=(("colour", colour),))]
        bt_build, new_build, bb_build = py_trees_running(colour)
        bt_pre, new_pre, bb_pre = py_trees_running(colour)
        return _MergeRound(
            text,
            when,
            kp.parse(text),
            parsed_when,
            ours_running(colour),
            ours_running(colour),
            bt_build,
            new_build,
            bb_build,
            colour,
            bt_pre,
            new_pre,
            py_trees_learned(bb_pre, colour),
        )

    # Sanity: both trees have the same shape.
    ours_nodes = sum(1 for _ in sar.walk())
    if ours_nodes != sum(1 for _ in py_trees_running(0)[0].root.iterate()):
        raise AssertionError("the py_trees SAR tree does not match examples/sar_control.sbt")

    names = list(MERGE_VARIANTS)
    variants = [MERGE_VARIANTS[name] for name in names]
    samples: dict[str, list[int]] = {name: [] for name in names}
    with gc_paused():
        for r in range(warmup + rounds):
            if r and r % 100 == 0:
                gc.collect()
            prepared = prepare(2 + r)
            shift = r % len(variants)
            for i in range(shift, shift + len(variants)):
                j = i % len(variants)
                elapsed, ok = variants[j](prepared)
                if not ok:
                    raise AssertionError(f"{names[j]}: the merge did not take effect")
                if r >= warmup:
                    samples[names[j]].append(elapsed)
    return {
        "sar_nodes": ours_nodes,
        "learned_nodes": 5,
        "rounds": rounds,
        **{name: _us_stats(Stats.of(s)) for name, s in samples.items()},
    }


# -- report ------------------------------------------------------------------------------------


def run(
    tick_rounds: int = TICK_ROUNDS,
    build_rounds: int = BUILD_ROUNDS,
    merge_rounds: int = MERGE_ROUNDS,
) -> dict[str, Any]:
    py_trees.logging.level = py_trees.logging.Level.ERROR
    started = time.perf_counter()
    result: dict[str, Any] = {
        "python": machine(),
        "py_trees": importlib.metadata.version("py_trees"),
        "ticks": {"rounds": tick_rounds, **run_ticks(tick_rounds)},
        "build": {"rounds": build_rounds, **run_build(build_rounds)},
        "merge": run_merge(merge_rounds),
    }
    result["targets"] = {
        "ours_over_py_trees_min": TARGET_TICK_RATIO,
        "livetree_from_text_us_max": TARGET_BUILD_US,
        "merge_and_tick_us_max": TARGET_MERGE_US,
    }
    result["seconds"] = round(time.perf_counter() - started, 1)
    return result


def _verdict(ok: bool) -> str:
    return "met" if ok else "missed"


def report(result: Mapping[str, Any]) -> str:
    ticks = result["ticks"]
    labels = {
        "ours": "ours: `live.tick()`",
        "py_trees": f"py_trees {result['py_trees']}: `BehaviourTree.tick()`",
        "flat": "flat Python loop (ceiling)",
    }
    rows = []
    for c in CONTENDERS:
        row = [labels[c]]
        for name in SCENARIOS:
            r = ticks[name][c]
            row += [
                f"{r['ticks_per_s']:,}",
                f"{r['us_per_tick']:.2f}",
                f"{r['over_py_trees']:.1f}x",
            ]
        rows.append(row)
    full_n, early_n = ticks["full"]["nodes_ticked"], ticks["early"]["nodes_ticked"]
    tick_table = markdown_table(
        [
            "51-node reference tree",
            f"full ({full_n} nodes): ticks/s",
            "µs/tick",
            "vs py_trees",
            f"early exit ({early_n} nodes): ticks/s",
            "µs/tick",
            "vs py_trees",
        ],
        rows,
    )
    verdicts = []
    for name in SCENARIOS:
        x = ticks[name]["ours"]["over_py_trees"]
        ceiling = ticks[name]["flat"]["us_per_tick"] / ticks[name]["ours"]["us_per_tick"]
        verdicts.append(
            f"{name}: {x:.1f}x ({_verdict(x >= TARGET_TICK_RATIO)}; "
            f"ours runs at {ceiling:.0%} of the flat loop's speed)"
        )
    tick_target = f"Target: ours ≥ {TARGET_TICK_RATIO:.0f}x py_trees. " + "; ".join(verdicts) + "."

    build, merge = result["build"], result["merge"]

    def us(d: Mapping[str, float]) -> list[str]:
        return [f"{d['median']:,.1f}", f"{d['p90']:,.1f}"]

    lv, lk = build["livetree"]["median"], build["lark"]["median"]
    mt = merge["ours_text"]["median"]
    op_rows = [
        [
            "`kp.LiveTree(text, reg)`: parse + validate + compile, 51 nodes",
            *us(build["livetree"]),
            f"≤ {TARGET_BUILD_US:.0f} µs: {_verdict(lv <= TARGET_BUILD_US)}",
        ],
        ["  of which `kp.parse(text)`", *us(build["parse"]), ""],
        ["  of which parse + `kp.validate(tree, reg)`", *us(build["parse_validate"]), ""],
        ["anchor: lark `_lark().parse(text)` (parse only)", *us(build["lark"]), ""],
        [
            f"hot merge: `live.merge(text, when=...)` + first tick ({merge['learned_nodes']} "
            f"nodes into the {merge['sar_nodes']}-node SAR tree)",
            *us(merge["ours_text"]),
            f"≤ {TARGET_MERGE_US:.0f} µs: {_verdict(mt <= TARGET_MERGE_US)}",
        ],
        [
            "hot merge of an already parsed subtree + first tick",
            *us(merge["ours_parsed"]),
            "",
        ],
        [
            "anchor: py_trees build 5 behaviours + `insert_subtree` + tick",
            *us(merge["py_trees_build"]),
            "",
        ],
        [
            "anchor: py_trees `insert_subtree` (prebuilt) + tick",
            *us(merge["py_trees_prebuilt"]),
            "",
        ],
    ]
    op_table = markdown_table(["operation", "median µs", "p90 µs", "target"], op_rows)
    note = (
        f"{result['python']}, py_trees {result['py_trees']}. Figures are medians from one run "
        f"({ticks['rounds']} interleaved rounds of tick batches: {FAST_BATCH} ticks per sample "
        f"for ours and the flat loop, {PY_TREES_BATCH['full']}/{PY_TREES_BATCH['early']} for "
        f"py_trees; {build['rounds']} interleaved rounds of building; {merge['rounds']} rounds "
        "of merging, each on fresh running trees with a new colour; gc off while timing). "
        f"`LiveTree(text)` took {lv / lk:.2f}x lark's parse time of the same text. "
        f"Whole run: {result['seconds']:.0f} s."
    )
    return "\n\n".join(["## Live runtime", tick_table, tick_target, op_table, note])


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_runtime")
    parser.add_argument("--tick-rounds", type=int, default=TICK_ROUNDS, help="tick rounds")
    parser.add_argument("--build-rounds", type=int, default=BUILD_ROUNDS, help="build rounds")
    parser.add_argument("--merge-rounds", type=int, default=MERGE_ROUNDS, help="merge rounds")
    parser.add_argument("--no-json", action="store_true", help="do not write results/runtime.json")
    args = parser.parse_args(argv)
    result = run(args.tick_rounds, args.build_rounds, args.merge_rounds)
    print(report(result))
    if not args.no_json:
        path = write_json("runtime", result)
        print(f"\nWrote {path.relative_to(path.parents[2])}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
