"""A py_trees learner: merge plus the first tick, against ``LiveTree`` on the same item, same run.

Run with ``python -m benchmarks.bench_pytrees_learner`` (or ``python -m benchmarks``). Prints a
Markdown table and writes ``benchmarks/results/pytrees_learner.json``.

The search-and-rescue control tree of ``examples/sar_control.sbt``, already running its
fallback,
learns the 5-node item ``Sequence(TargetSeen(colour), Sequence(PickTreasure,
AssignCollectionPoint(colour)))`` into its ``new`` placeholder; the time covers the merge of the
item and the first tick (which puts it in and runs it), the item already parsed or as the
answer's text (parse included, as an agent receives it). Contenders, each on a fresh running
tree every round (built outside the timed region), in rotating order:

* the anchors: ``LiveTree.merge`` + ``tick``, parsed and from text;
* ``PyTreesControl`` over the same tree written in py_trees (``bench_runtime.py_trees_sar``),
  the item's leaves built from the registry (the py_trees builder) or from the user's own
  behaviour factories; and the latter from text;
* for scale, bare py_trees: ``insert_subtree`` of the same 5 behaviours, prebuilt, + the
  learner's tick (``tick_tree``; no check, no build).

Target (``spec/protocol.md`` section 4.4): the py_trees learner at most 2x its anchor.
"""

from __future__ import annotations

import argparse
import gc
import importlib.metadata
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import py_trees
from py_trees.common import Status as PtStatus

import ktbt_proto as kp
from ktbt_proto.interop.pytrees_control import PyTreesControl, tick_tree

from .bench_runtime import (
    SAR_PATH,
    _pt_action,
    _PtTargetSeen,
    learned_text,
    py_trees_learned,
    py_trees_sar,
    sar_vocabulary,
)
from .timing import Stats, gc_paused, machine, markdown_table, write_json

ROUNDS = 1500
TARGET_RATIO = 2.0
NAMES = (
    "livetree",
    "py_trees_registry",
    "py_trees_own",
    "py_trees_bare",
    "livetree_text",
    "py_trees_own_text",
)
ANCHOR = {name: "livetree_text" if name.endswith("_text") else "livetree" for name in NAMES}


@dataclass
class _Round:
    """One round's fresh trees and item, prepared outside the timed region."""

    colour: int
    item: kp.Tree
    when: list[kp.Condition]
    text: str
    text_when: list[str]
    live: kp.LiveTree
    registry_leaves: PyTreesControl
    own_leaves: PyTreesControl
    live_text: kp.LiveTree
    own_text: PyTreesControl
    bare: py_trees.trees.BehaviourTree
    bare_new: py_trees.composites.Selector
    bare_item: py_trees.behaviour.Behaviour


def _own(bb: Any) -> dict[str, Callable[..., py_trees.behaviour.Behaviour]]:
    """The user's own behaviours for the item's leaves (those the bare py_trees tree uses)."""
    return {
        "TargetSeen": lambda colour: _PtTargetSeen(bb, colour),
        "PickTreasure": lambda: _pt_action("PickTreasure"),
        "AssignCollectionPoint": lambda colour: _pt_action("AssignCollectionPoint"),
    }


def _prepare(colour: int, sar: kp.Tree, reg: kp.Registry) -> _Round:
    def learner(own: bool) -> PyTreesControl:
        bb = kp.Blackboard(target=colour)
        bt, new = py_trees_sar(bb)
        new.name = "k:new"  # the placeholder, as spec/protocol.md section 4.4 names it
        control = PyTreesControl(bt, reg, bb, behaviours=_own(bb) if own else None)
        if control.tick() is not kp.RUNNING:
            raise AssertionError("the py_trees SAR tree should be running its fallback")
        return control

    def live() -> kp.LiveTree:
        tree = kp.LiveTree(sar, reg, kp.Blackboard(target=colour))
        if tree.tick() is not kp.RUNNING:
            raise AssertionError("the SAR tree should be running its fallback")
        return tree

    bb: dict[str, Any] = {"target": colour}
    bare, bare_new = py_trees_sar(bb)
    bare.tick()
    return _Round(
        colour,
        kp.parse(learned_text(colour)),
        [kp.Condition("TargetSeen", args=(("colour", colour),))],
        learned_text(colour),
        [f"TargetSeen(colour={colour})"],
        live(),
        learner(False),
        learner(True),
        live(),
        learner(True),
        bare,
        bare_new,
        py_trees_learned(bb, colour),
    )


Timed = tuple[int, bool]


def _live(p: _Round) -> Timed:
    clock = time.perf_counter_ns
    start = clock()
    p.live.merge(p.item, "new", when=p.when)
    status = p.live.tick()
    return clock() - start, status is kp.SUCCESS


def _live_text(p: _Round) -> Timed:
    clock = time.perf_counter_ns
    start = clock()
    p.live_text.merge(p.text, "new", when=p.text_when)
    status = p.live_text.tick()
    return clock() - start, status is kp.SUCCESS


def _learner(control: Callable[[_Round], PyTreesControl]) -> Callable[[_Round], Timed]:
    def run(p: _Round) -> Timed:
        learner, clock = control(p), time.perf_counter_ns
        start = clock()
        learner.merge(p.item, "new", when=p.when)
        status = learner.tick()
        return clock() - start, status is kp.SUCCESS

    return run


def _learner_text(p: _Round) -> Timed:
    learner, clock = p.own_text, time.perf_counter_ns
    start = clock()
    learner.merge(p.text, "new", when=p.text_when)
    status = learner.tick()
    return clock() - start, status is kp.SUCCESS


def _bare(p: _Round) -> Timed:
    bt, new, clock = p.bare, p.bare_new, time.perf_counter_ns
    start = clock()
    bt.insert_subtree(p.bare_item, new.id, len(new.children))
    tick_tree(bt)  # the learner's own tick, so the row differs from it only in the merge
    return clock() - start, bt.root.status is PtStatus.SUCCESS


VARIANTS: dict[str, Callable[[_Round], Timed]] = {
    "livetree": _live,
    "py_trees_registry": _learner(lambda p: p.registry_leaves),
    "py_trees_own": _learner(lambda p: p.own_leaves),
    "py_trees_bare": _bare,
    "livetree_text": _live_text,
    "py_trees_own_text": _learner_text,
}


def run(rounds: int = ROUNDS, warmup: int = 30) -> dict[str, Any]:
    py_trees.logging.level = py_trees.logging.Level.ERROR
    started = time.perf_counter()
    sar = kp.parse(SAR_PATH.read_text(encoding="utf-8"))
    reg = sar_vocabulary()
    calls = [VARIANTS[name] for name in NAMES]
    samples: dict[str, list[int]] = {name: [] for name in NAMES}
    with gc_paused():
        for r in range(warmup + rounds):
            if r and r % 100 == 0:
                gc.collect()
            prepared = _prepare(2 + r, sar, reg)
            for i in range(r, r + len(calls)):
                j = i % len(calls)
                elapsed, ok = calls[j](prepared)
                if not ok:
                    raise AssertionError(f"{NAMES[j]}: the learned item did not run")
                if r >= warmup:
                    samples[NAMES[j]].append(elapsed)
    stats = {name: Stats.of(s) for name, s in samples.items()}
    return {
        "python": machine(),
        "py_trees": importlib.metadata.version("py_trees"),
        "rounds": rounds,
        **{
            name: {
                "median_us": round(st.median_us, 1),
                "p90_us": round(st.p90_us, 1),
                "over_livetree": round(st.median_ns / stats[ANCHOR[name]].median_ns, 2),
            }
            for name, st in stats.items()
        },
        "target_over_livetree_max": TARGET_RATIO,
        "seconds": round(time.perf_counter() - started, 1),
    }


LABELS = {
    "livetree": "anchor: `LiveTree.merge` + first tick",
    "py_trees_registry": "`PyTreesControl.merge` + first tick, leaves from the registry",
    "py_trees_own": "`PyTreesControl.merge` + first tick, the user's own behaviours",
    "py_trees_bare": "bare py_trees: `insert_subtree` (prebuilt, unchecked) + tick",
    "livetree_text": "anchor from text: `LiveTree.merge(text)` + first tick",
    "py_trees_own_text": "`PyTreesControl.merge(text)` + first tick, the user's own behaviours",
}
TARGETED = ("py_trees_registry", "py_trees_own", "py_trees_own_text")


def report(result: Mapping[str, Any]) -> str:
    rows = []
    for name in NAMES:
        r = result[name]
        verdict = ""
        if name in TARGETED:
            ok = r["over_livetree"] <= TARGET_RATIO
            verdict = f"≤ {TARGET_RATIO:.0f}x: {'met' if ok else 'missed'}"
        rows.append(
            [
                LABELS[name],
                f"{r['median_us']:,.1f}",
                f"{r['p90_us']:,.1f}",
                f"{r['over_livetree']:.2f}x {ANCHOR[name]}",
                verdict,
            ]
        )
    table = markdown_table(
        ["merge of a 5-node item", "median µs", "p90 µs", "ratio", "target"], rows
    )
    note = (
        f"{result['python']}, py_trees {result['py_trees']}: {result['rounds']} rounds, each on "
        f"fresh running trees with a new colour, in rotating order; gc off while timing. "
        f"Whole run: {result['seconds']:.0f} s."
    )
    return "\n\n".join(["## py_trees learner", table, note])


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_pytrees_learner")
    parser.add_argument("--rounds", type=int, default=ROUNDS, help="timed rounds")
    parser.add_argument("--no-json", action="store_true", help="do not write the results file")
    args = parser.parse_args(argv)
    result = run(args.rounds)
    print(report(result))
    if not args.no_json:
        path = write_json("pytrees_learner", result)
        print(f"\nWrote {path.relative_to(path.parents[2])}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
