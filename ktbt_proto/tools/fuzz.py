"""Mutation fuzzing of what a peer or a file can feed us: ``make fuzz`` (``python -m
ktbt_proto.tools.fuzz``).

Inputs are mutations of a seed corpus (the conformance vectors, the examples and wire
messages): bit and byte flips, stringBT tokens and hostile literals inserted, spans deleted,
duplicated or spliced from another seed, nesting deepened. Every input is checked against the
properties the specification promises:

- the parser returns a tree or raises a ``StringBTError``, for str and bytes alike, and never
  anything else (``spec/stringbt.md`` sections 8 and 9);
- the fast parser and the reference parser agree: the same tree, or the same error code at the
  same position (section 9);
- a tree that parses formats, in both styles, to text that parses back to the same tree
  (section 6: ``parse(format(t)) == t``);
- the validator, with and without a registry, returns problems and raises nothing;
- the message decoder returns a message or raises ``MessageRefused``; a message that decodes
  encodes and decodes back to itself (``spec/protocol.md`` section 1).

A failing input is written to ``fuzz-failures/`` with the property it broke, and the run ends
with exit status 1. The run reports inputs per second.
"""

from __future__ import annotations

import argparse
import json
import random
import re
import sys
import time
import traceback
from collections.abc import Callable
from pathlib import Path

from ktbt_proto.errors import StringBTError
from ktbt_proto.exchange.messages import MessageRefused, Query, Response, decode, encode
from ktbt_proto.files import packaged
from ktbt_proto.formatter import format_tree
from ktbt_proto.registry import Registry
from ktbt_proto.syntax import parse, parse_reference
from ktbt_proto.validate import find_problems

ROOT = Path(__file__).resolve().parents[2]  # the repository, for its spec/vectors

TOKENS = [
    "<sq>",
    "<msq>",
    "<sl>",
    "<msl>",
    "<pl>",
    "<pl>(2)",
    "<neg>",
    "<tt1>(3)",
    "<tt2>(3)",
    "<k>(new)",
    "<e>",
    "<c>(A)",
    "<c>(!B)",
    "<a>(X)",
    "<a>(X,k=1)",
    "<w>(2)",
    "<wt>(0.5)",
    "<Root>",
    "<foo>",
    "(",
    ")",
    ",",
    "=",
    "!",
    "#",
    "# c\n",
    "\n",
    " ",
    "\t",
    "\r\n",
    '"',
    '"\\ud800"',
    '"\\uD800\\udc00"',
    "\\u0000",
    "1e400",
    "-1e400",
    "1e308",
    "-0.0",
    "9" * 300,
    "true",
    "false",
    "é",
    "\ufeff",
    "\x00",
    "\udfff",
    "💡",
    "<c>",
    "<a>",
    "<w>",
    "k=",
    ",y=",
]
"""Fragments worth inserting: every tag, punctuation, and the literals that broke things."""

MESSAGE_FIELDS: list[tuple[str, object]] = [
    ("v", True),
    ("v", 1.0),
    ("v", 2),
    ("type", "q" * 1000),
    ("type", "teach"),
    ("id", ""),
    ("id", "a b"),
    ("sender", "x" * 65),
    ("sequence", ""),
    ("subtree", "\x01" * 2000),
    ("author", "A" * 43),
    ("signature", "A" * 86),
    ("key", "A" * 42),
    ("hop", None),
    ("extra", 1),
    ("sequence", ["nested"]),
    ("subtree", {"a": 1}),
]


def seed_corpus() -> tuple[list[str], list[bytes]]:
    """stringBT seeds (vectors and examples) and message seeds (valid messages)."""
    texts: list[str] = []
    for name in ("valid", "invalid", "validation"):
        path = ROOT / "spec" / "vectors" / f"{name}.json"
        if path.exists():
            texts += [case["input"] for case in json.loads(path.read_text(encoding="utf-8"))]
    for path in sorted(packaged("examples").rglob("*.sbt")):
        texts.append(path.read_text(encoding="utf-8"))
    texts = [t for t in texts if len(t) <= 20_000] or ["<sq><c>(A)<a>(B)<e>"]
    messages = [
        encode(Query(id="q1", sender="r1", sequence="<c>(TargetSeen,colour=2)")),
        encode(
            Response(
                id="q1",
                sender="r2",
                sequence="<c>(TargetSeen,colour=2)",
                subtree="<sq><a>(PickTreasure)<a>(AssignCollectionPoint,colour=2)<e>",
            )
        ),
        b'{"v":1,"type":"error","id":"0","sender":"r","code":"refused","message":"bad"}',
    ]
    signing = ROOT / "spec" / "vectors" / "signing.json"
    if signing.exists():
        vector = json.loads(signing.read_text(encoding="utf-8"))
        messages.append(json.dumps(vector["response"], ensure_ascii=False).encode())
    return texts, messages


NUMBERS = ["0", "-0.0", "1.5", "2.5e-07", "1e+16", "1e308", "-1e308", "1e400", "9" * 300, "7"]
STRINGS = ['"\\ud800"', '"é\\u0000"', '"\\uD800\\udc00"', '"💡"', '"a\\nb"', '""', '"#(<e>"']
LEAVES = ["<a>(X)", "<c>(A)", "<c>(!A)", "<w>(1)", "<wt>(0.25)", "<a>(X, k=1)", '<c>(B,k="s")']
_NUMBER_RE = re.compile(r"-?[0-9]+(?:\.[0-9]+)?(?:[eE][+-]?[0-9]+)?")
_STRING_RE = re.compile(r'"(?:[^"\\]|\\.)*"')
_OPEN_RE = re.compile(r"<(?:sq|msq|sl|msl|neg|pl)>|<(?:pl|tt1|tt2|k)>\([^)]*\)")


def _gentle(rng: random.Random, text: str) -> str:
    """A mutation that keeps most texts valid: a literal swapped for a hostile one, a leaf
    added to a container, a comment put between two tokens."""
    kind = rng.randrange(4)
    pattern = (_NUMBER_RE, _STRING_RE, _OPEN_RE, _OPEN_RE)[kind]
    spots = list(pattern.finditer(text))
    if not spots:
        return text
    m = rng.choice(spots)
    if kind == 0:
        return text[: m.start()] + rng.choice(NUMBERS) + text[m.end() :]
    if kind == 1:
        return text[: m.start()] + rng.choice(STRINGS) + text[m.end() :]
    if kind == 2:
        return text[: m.end()] + rng.choice(LEAVES) + text[m.end() :]
    return text[: m.end()] + rng.choice(("  # a (comment) <e>\n", "\n#)\n", " ")) + text[m.end() :]


def mutate_text(rng: random.Random, text: str, corpus: list[str]) -> str:
    """Gentle mutations half the time (most stay valid, and exercise the round trip), else one
    to four rough ones."""
    if rng.random() < 0.5:
        for _ in range(rng.randint(1, 3)):
            text = _gentle(rng, text)
        return text
    for _ in range(rng.randint(1, 4)):
        n = len(text)
        i, j = sorted((rng.randint(0, n), rng.randint(0, n)))
        kind = rng.randrange(8)
        if kind == 0:
            text = text[:i] + rng.choice(TOKENS) + text[i:]
        elif kind == 1:
            text = text[:i] + text[j:]
        elif kind == 2:
            text = text[:i] + text[i:j] * rng.randint(2, 4) + text[j:]
        elif kind == 3 and n:
            c = chr(rng.choice((rng.randrange(32, 127), rng.randrange(0, 0x3000))))
            text = text[:i] + c + text[i + 1 :]
        elif kind == 4:
            other = rng.choice(corpus)
            a, b = sorted((rng.randint(0, len(other)), rng.randint(0, len(other))))
            text = text[:i] + other[a:b] + text[j:]
        elif kind == 5:
            depth = rng.choice((2, 8, 40, 200))
            text = "<sq>" * depth + text + "<e>" * rng.choice((depth, depth - 1, 0))
        elif kind == 6:
            text = text[:i] + text[i:j].swapcase() + text[j:]
        else:
            text = text[:i] + "".join(rng.choices(TOKENS, k=rng.randint(1, 6))) + text[j:]
    return text[:20_000]


def mutate_message(rng: random.Random, data: bytes) -> bytes:
    """A wire message with fields changed, or its bytes mangled."""
    if rng.random() < 0.5:
        try:
            obj = json.loads(data)
        except ValueError:
            obj = None
        if isinstance(obj, dict):
            for _ in range(rng.randint(1, 3)):
                key, value = rng.choice(MESSAGE_FIELDS)
                if value is None:
                    obj.pop(key, None)
                else:
                    obj[key] = value
            return json.dumps(obj, ensure_ascii=rng.random() < 0.5).encode("utf-8", "replace")
    raw = bytearray(data)
    for _ in range(rng.randint(1, 6)):
        if not raw:
            break
        i = rng.randrange(len(raw))
        choice = rng.randrange(4)
        if choice == 0:
            raw[i] = rng.randrange(256)
        elif choice == 1:
            del raw[i : i + rng.randint(1, 8)]
        elif choice == 2:
            raw[i:i] = rng.choice((b"{", b"[", b'"', b"\\u0000", b"\xff", b"1e999", b"{" * 100))
        else:
            raw[i] ^= 1 << rng.randrange(8)
    return bytes(raw)


class Failure(Exception):
    """A property broken by one input."""


def _fuzz_registry() -> Registry:
    reg = Registry()
    reg.add_condition("A", lambda bb: True)
    reg.add_condition("B", lambda bb, k: True)

    def x(bb: object, k: int = 0) -> bool:
        return True

    reg.add_action("X", x)
    return reg


def check_text(text: str, registry: Registry) -> None:
    """Every property of section "the parser", for one text."""
    outcome: list[object] = []
    for parser in (parse, parse_reference):
        try:
            outcome.append(parser(text).root)
        except StringBTError as err:
            outcome.append((err.code, err.line, err.column))
        except Exception as exc:
            raise Failure(f"{parser.__name__} raised {type(exc).__name__}: {exc}") from exc
    fast, reference = outcome
    if fast != reference:
        raise Failure(f"parse gives {fast!r:.200}, parse_reference gives {reference!r:.200}")
    try:
        data = text.encode("utf-8")
    except UnicodeEncodeError:
        data = None
    if data is not None:
        try:
            by_bytes: object = parse(data).root
        except StringBTError as err:
            by_bytes = (err.code, err.line, err.column)
        except Exception as exc:
            raise Failure(f"parse(bytes) raised {type(exc).__name__}: {exc}") from exc
        if by_bytes != fast and not (isinstance(fast, tuple) and isinstance(by_bytes, tuple)):
            raise Failure("parse of the text and of its UTF-8 bytes disagree")
    if isinstance(fast, tuple):
        return
    tree = parse(text)
    for reg in (None, registry):
        try:
            find_problems(tree, reg)
        except Exception as exc:
            raise Failure(f"check raised {type(exc).__name__}: {exc}") from exc
    for style in ("compact", "pretty"):
        try:
            written = format_tree(tree, style)
            again = parse(written)
        except StringBTError as err:
            raise Failure(f"format ({style}) or its reparse raised {err}") from err
        except Exception as exc:
            raise Failure(f"format ({style}) raised {type(exc).__name__}: {exc}") from exc
        if again.root != tree.root:
            raise Failure(f"the {style} round trip changed the tree: {written[:200]!r}")


def check_message(data: bytes) -> None:
    try:
        message = decode(data)
    except MessageRefused:
        return
    except Exception as exc:
        raise Failure(f"decode raised {type(exc).__name__}: {exc}") from exc
    if decode(encode(message)) != message:
        raise Failure("a decoded message does not survive encode and decode")
    sent = json.loads(data)
    if type(sent.get("v")) is not int or "type" not in sent:
        raise Failure(f"a message with v={sent.get('v')!r:.20} or no type was accepted")


def run(
    inputs: int,
    seed: int,
    out: Path,
    report: Callable[[str], None] = print,
    every: float = 30.0,
) -> int:
    """Fuzz ``inputs`` inputs; returns the number of failures (each saved under ``out``)."""
    rng = random.Random(seed)
    texts, messages = seed_corpus()
    registry = _fuzz_registry()
    failures = 0
    start = last = time.perf_counter()
    for n in range(1, inputs + 1):
        if rng.random() < 0.2:
            data = mutate_message(rng, rng.choice(messages))
            target, body = "message", data
            try:
                check_message(data)
                error = None
            except Failure as exc:
                error = exc
        else:
            text = mutate_text(rng, rng.choice(texts), texts)
            target, body = "text", text.encode("utf-8", "surrogatepass")
            try:
                check_text(text, registry)
                error = None
            except Failure as exc:
                error = exc
        if error is not None:
            failures += 1
            out.mkdir(parents=True, exist_ok=True)
            stem = out / f"{target}-{seed}-{n}"
            stem.with_suffix(".bin").write_bytes(body)
            stem.with_suffix(".txt").write_text(
                f"{error}\n\n{''.join(traceback.format_exception(error))}", encoding="utf-8"
            )
            report(f"FAIL {stem.name}: {error}")
        now = time.perf_counter()
        if now - last >= every:
            last = now
            report(f"{n:,} inputs, {n / (now - start):,.0f}/s, {failures} failures")
    elapsed = time.perf_counter() - start
    report(
        f"done: {inputs:,} inputs in {elapsed:,.0f} s ({inputs / elapsed:,.0f} inputs/s), "
        f"seed {seed}, {failures} failures"
    )
    return failures


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ktbt_proto.tools.fuzz", description=__doc__)
    parser.add_argument("--inputs", type=int, default=100_000, help="how many inputs")
    parser.add_argument("--seed", type=int, default=None, help="random seed (default: time)")
    parser.add_argument("--out", type=Path, default=Path("fuzz-failures"))
    args = parser.parse_args(argv)
    seed = args.seed if args.seed is not None else int(time.time())
    failures = run(args.inputs, seed, args.out, lambda line: print(line, flush=True))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
