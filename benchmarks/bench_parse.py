"""Parse speed of ``ktbt_proto.parse`` against lark's LALR parser on the normative grammar.

Run with ``python -m benchmarks.bench_parse`` (or ``python -m benchmarks`` for every module).
Prints Markdown tables and writes the numbers to ``benchmarks/results/parse.json``.

The anchor is ``_lark().parse(text)``: lark alone, building its own parse tree from the same
text, without the conversion to our tree that ``parse_reference`` adds. A ratio above 1 means
ours is faster than lark by that factor.
"""

from __future__ import annotations

import argparse
import importlib.metadata
from collections.abc import Sequence
from typing import Any

import ktbt_proto as kp
from ktbt_proto.limits import DEFAULT_LIMITS
from ktbt_proto.syntax import _lark, parse_reference

from .timing import Stats, interleaved, machine, markdown_table, time_once, write_json

ROUNDS = 1500
"""Interleaved rounds for the 51-node tree (each round times every case once)."""
BIG_REPEATS = 5
"""Timed parses of the ~1 MB tree, per parser."""
BIG_SIZE = 1_000_000
"""Target size of the big tree, in characters (ASCII, so also bytes)."""


def reference_compact() -> str:
    """The 51-node reference tree: a Selector over 10 Sequences of two conditions, two actions."""
    body = "".join(f"<sq><c>(Cond{i}a)<c>(!Cond{i}b)<a>(Act{i}a)<a>(Act{i}b)<e>" for i in range(10))
    return f"<sl>{body}<e>"


_VERBS = ("Pick", "Place", "Inspect", "Charge", "Patrol", "Dock", "Scan")
_OBJECTS = ("crate", "pallet", "door", "shelf", "marker", "beacon")


def _branch(i: int) -> str:
    """One Sequence of varied leaves, in the canonical pretty form (4-space indents)."""
    verb = _VERBS[i % len(_VERBS)]
    obj = _OBJECTS[i % len(_OBJECTS)]
    x = (i % 40) / 4 - 5  # quarter steps: exact, short decimal literals
    y = -(i % 9)
    lines = [
        f"    # branch {i}: {verb.lower()} the {obj} near ({x}, {y})",
        "    <sq>",
        f"        <c>(Ready{i % 97})",
        f"        <c>(!Blocked.zone{i % 13})  # skip blocked zones",
        f"        <c>(Battery.ok, min={(i % 5 + 1) / 8})",
        f'        <a>(MoveTo, x={x}, y={y}, tag="{obj}-{i}")',
    ]
    if i % 3 == 0:
        lines += [
            "        <neg>",
            f'            <c>(Holding, item="{obj}")',
            "        <e>",
        ]
    if i % 4 == 1:
        lines.append(f"        <w>({i % 7 + 1})")
    lines += [
        f"        <a>({verb}, target={i}, careful={'true' if i % 2 else 'false'})",
        f"        <a>(Report{i % 11})",
        "    <e>",
    ]
    return "\n".join(lines) + "\n"


def big_pretty(size: int = BIG_SIZE) -> str:
    """A deterministic tree of about ``size`` characters in pretty form, with comments."""
    head = "# Benchmark tree: a Selector over many Sequences with varied leaves.\n<sl>\n"
    tail = "<e>\n"
    parts = [head]
    total = len(head) + len(tail)
    i = 0
    while total < size:
        branch = _branch(i)
        parts.append(branch)
        total += len(branch)
        i += 1
    parts.append(tail)
    return "".join(parts)


def _limits_for(text: str) -> kp.Limits:
    # Generous bounds for a generated tree: size and node count scale with the text.
    return kp.Limits(max_size=2 * len(text), max_nodes=len(text) // 4, max_depth=128)


def _check_inputs(compact: str, pretty: str, big: str, big_limits: kp.Limits) -> int:
    """Make sure every input is valid stringBT on which both parsers agree; return the big
    tree's node count."""
    for text, limits in ((compact, DEFAULT_LIMITS), (pretty, DEFAULT_LIMITS)):
        tree = kp.parse(text, limits=limits)
        kp.validate(tree, limits=limits)
        assert tree == parse_reference(text, limits=limits)
    big_tree = kp.parse(big, limits=big_limits)
    kp.validate(big_tree, limits=big_limits)
    if kp.format_tree(big_tree) != big:
        raise AssertionError("the big tree is not in canonical pretty form")
    return sum(1 for _ in big_tree.walk())


def _us(value: float) -> str:
    return f"{value:,.1f}"


def run(rounds: int = ROUNDS, big_repeats: int = BIG_REPEATS) -> dict[str, Any]:
    lark_parser = _lark()  # built (and cached) here, outside any timing
    compact = reference_compact()
    pretty = kp.format_tree(kp.parse(compact), "pretty")
    big = big_pretty()
    big_limits = _limits_for(big)
    big_nodes = _check_inputs(compact, pretty, big, big_limits)

    def parse_and_validate(text: str) -> None:
        kp.validate(kp.parse(text))

    forms = {"compact": compact, "pretty": pretty}
    cases: dict[str, Any] = {}
    for form, text in forms.items():
        cases[f"{form}/parse"] = lambda t=text: kp.parse(t)
        cases[f"{form}/parse+validate"] = lambda t=text: parse_and_validate(t)
        cases[f"{form}/lark"] = lambda t=text: lark_parser.parse(t)
    small = interleaved(cases, rounds=rounds)

    # The ~1 MB tree: few repetitions, alternating ours and lark.
    big_samples: dict[str, list[int]] = {"parse": [], "lark": []}
    for _ in range(big_repeats):
        big_samples["parse"].append(time_once(lambda: kp.parse(big, limits=big_limits)))
        big_samples["lark"].append(time_once(lambda: lark_parser.parse(big)))
    big_stats = {name: Stats.of(samples) for name, samples in big_samples.items()}

    result: dict[str, Any] = {
        "python": machine(),
        "lark": importlib.metadata.version("lark"),
        "tree_51": {"rounds": rounds},
        "tree_1mb": {"chars": len(big), "nodes": big_nodes, "repeats": big_repeats},
    }
    for form, text in forms.items():
        p, pv, lk = (small[f"{form}/{k}"] for k in ("parse", "parse+validate", "lark"))
        result["tree_51"][form] = {
            "chars": len(text),
            "parse_us": {"median": round(p.median_us, 1), "p90": round(p.p90_us, 1)},
            "parse_validate_us": {"median": round(pv.median_us, 1), "p90": round(pv.p90_us, 1)},
            "lark_us": {"median": round(lk.median_us, 1), "p90": round(lk.p90_us, 1)},
            "lark_over_parse": round(lk.median_ns / p.median_ns, 2),
            "lark_over_parse_validate": round(lk.median_ns / pv.median_ns, 2),
        }
    mb = len(big) / 1e6
    for name in ("parse", "lark"):
        result["tree_1mb"][f"{name}_ms"] = round(big_stats[name].median_ns / 1e6, 1)
        result["tree_1mb"][f"{name}_mb_s"] = round(mb / (big_stats[name].median_ns / 1e9), 2)
    result["tree_1mb"]["lark_over_parse"] = round(
        big_stats["lark"].median_ns / big_stats["parse"].median_ns, 2
    )
    return result


def report(result: dict[str, Any]) -> str:
    t51 = result["tree_51"]
    rows = []
    for form in ("compact", "pretty"):
        r = t51[form]
        rows.append(
            [
                f"51 nodes, {form} ({r['chars']} chars)",
                f"{_us(r['parse_us']['median'])} ({_us(r['parse_us']['p90'])})",
                f"{_us(r['parse_validate_us']['median'])} ({_us(r['parse_validate_us']['p90'])})",
                f"{_us(r['lark_us']['median'])} ({_us(r['lark_us']['p90'])})",
                f"{r['lark_over_parse']:.1f}x",
                f"{r['lark_over_parse_validate']:.1f}x",
            ]
        )
    small_table = markdown_table(
        [
            "input",
            "parse µs (p90)",
            "parse+validate µs (p90)",
            "lark µs (p90)",
            "lark / parse",
            "lark / parse+validate",
        ],
        rows,
    )
    big = result["tree_1mb"]
    big_table = markdown_table(
        ["input", "parse MB/s", "lark MB/s", "parse ms", "lark ms", "lark / parse"],
        [
            [
                f"{big['chars'] / 1e6:.2f} MB, pretty with comments ({big['nodes']:,} nodes)",
                f"{big['parse_mb_s']:.2f}",
                f"{big['lark_mb_s']:.2f}",
                f"{big['parse_ms']:,.1f}",
                f"{big['lark_ms']:,.1f}",
                f"{big['lark_over_parse']:.1f}x",
            ]
        ],
    )
    note = (
        f"{result['python']}, lark {result['lark']}. Figures are medians from one run "
        f"({t51['rounds']} interleaved rounds for the 51-node tree, {big['repeats']} alternating "
        "parses of the 1 MB tree; gc off while timing); lark = `_lark().parse(text)` alone."
    )
    return "\n\n".join(["## Parse speed", small_table, big_table, note])


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_parse")
    parser.add_argument("--rounds", type=int, default=ROUNDS, help="rounds, 51-node tree")
    parser.add_argument("--big-repeats", type=int, default=BIG_REPEATS, help="1 MB parses")
    parser.add_argument("--no-json", action="store_true", help="do not write results/parse.json")
    args = parser.parse_args(argv)
    result = run(rounds=args.rounds, big_repeats=args.big_repeats)
    print(report(result))
    if not args.no_json:
        path = write_json("parse", result)
        print(f"\nWrote {path.relative_to(path.parents[2])}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
