"""Mutation fuzzing of what a peer or a file can feed us: ``make fuzz`` (``python -m
ktbt_proto.tools.fuzz``).

Every input is checked against the properties the specification promises:

- the parser returns a tree or raises a ``StringBTError``, for str and bytes alike, and never
  anything else (``spec/stringbt.md`` sections 8 and 9);
- the fast parser and the reference parser agree: the same tree, or the same error code at the
  same position (section 9);
- a tree that parses formats, in both styles, to text that parses back to the same tree
  (section 6: ``parse(format(t)) == t``);
- the validator, with and without a registry, returns problems and raises nothing;
- the message decoder returns a message or raises ``MessageRefused``; a message that decodes
  encodes and decodes back to itself (``spec/protocol.md`` section 1).

Inputs are mutations of the seeds: the conformance vectors (``spec/vectors/``), every ``.sbt``
file of the repository (the packaged examples, outside a source checkout) and wire messages.
Bugs in a parser hide where tokens meet, so most mutations know the tokens of section 1: a
name, number, string or boolean is swapped for another literal (``true``, ``1e400``, a JSON
fragment), a fragment is glued right after or before a token (``.``, ``.5``, ``1e``, ``(``), a
leaf is rewritten with or without its parentheses (``<c>X`` is ``<c>(X)``, section 2) around
another literal, tags are swapped, dropped or doubled, and leaves and subtrees cut from the
seeds are spliced in. A leaf, a subtree or a whole seed is the starting point, so the short
inputs where such bugs show are common. Rougher mutations (characters flipped, spans deleted,
duplicated or spliced from another seed, nesting deepened) and gentle ones (a literal changed in
a valid text, so that the round trip is exercised) make up the rest. The inputs that broke
something once are kept in ``tests/data/fuzz/`` and checked by ``make test``.

A failing input is written to ``fuzz-failures/`` with the property it broke, and the run ends
with exit status 1. A run lasts a set time or a set number of inputs, on one worker process per
core, and reports inputs per second over all workers; an input drawn twice is checked and
counted once.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import queue
import random
import re
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ktbt_proto.errors import StringBTError
from ktbt_proto.exchange.messages import MessageRefused, Query, Response, decode, encode
from ktbt_proto.files import packaged
from ktbt_proto.formatter import format_tree
from ktbt_proto.registry import Registry
from ktbt_proto.syntax import parse, parse_reference
from ktbt_proto.validate import find_problems

ROOT = Path(__file__).resolve().parents[2]  # the repository, for its spec/vectors and .sbt files
MAX_TEXT = 20_000
"""Longer inputs cost time and find nothing the size limit tests do not (section 8)."""

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

TAGS = [
    "<sq>",
    "<msq>",
    "<sl>",
    "<msl>",
    "<pl>",
    "<neg>",
    "<tt1>",
    "<tt2>",
    "<k>",
    "<e>",
    "<c>",
    "<a>",
    "<w>",
    "<wt>",
    "<Root>",
    "<foo>",
    "<C>",
    "<>",
    "<e",
    "e>",
    "<sq",
]
"""The tags of section 1, and near misses of them."""

NAMES = ["A", "B", "X", "TargetSeen", "nav.MoveTo", "_x", "k", "colour", "e", "sq", "Root", "a1"]
"""Names the fuzz registry knows, and names that look like tags."""

LITERALS = [
    ["true", "false", "null"],
    ["True", "FALSE", "truex", "true_", "false1", "true.x", "false.e_", "falsetrue"],
    ["0", "-0.0", "7", "1.5", "2.5e-07", "1e+16", "1e308", "-1e308", "1e400", "-1e400", "9" * 300],
    [".5", "1.", "1e", "1e+", "-", "--1", "0x10", "1.5.5", "1e5e5"],
    ["a.b.c", "a..b", "a.", ".a", "é", "x" * 1025],
]
"""Section 1's literals, in groups: the keywords, names that start as a keyword, numbers, near
numbers, near names (and a name one character over the literal limit of section 8). A group is
drawn first, so that the long ones do not drown the short."""

JSON_FRAGMENTS = [
    '""',
    '"s"',
    '"é\\u0000"',
    '"\\ud800"',
    '"\\uD800\\udc00"',
    '"\\/"',
    '"\\b\\f"',
    '"a\\"b"',
    '"\\x"',
    '"\\u12"',
    '"a\nb"',
    '"💡"',
    '"#(<e>"',
    '{"a":1}',
    "[1,2]",
    "[]",
    "{}",
    "-0",
    "1E5",
    "1e999",
]
"""JSON values and near misses: a stringBT string is a JSON string (section 1), a message is
JSON (``spec/protocol.md`` section 1)."""

GLUE = [
    [".", "..", ".5", ".x", ".true", ".e", "._"],
    ["1e", "e5", "e", "E+", "_", "0", "-", "x"],
    ["(", ")", "()", ",", "=", "!", "<", ">", "<e>", '"', "\\"],
    [" ", "\n", "\r", "#", "# (<e>\n", "\x00", "é"],
]
"""What may be glued to a token with no blank between, in groups: what continues a name (or
does not), a number, what ends a leaf, blanks and odd characters."""

WORDS = [NAMES, *LITERALS, JSON_FRAGMENTS]


NUMBERS = ["0", "-0.0", "1.5", "2.5e-07", "1e+16", "1e308", "-1e308", "1e400", "9" * 300, "7"]
STRINGS = ['"\\ud800"', '"é\\u0000"', '"\\uD800\\udc00"', '"💡"', '"a\\nb"', '""', '"#(<e>"']
LEAVES = ["<a>(X)", "<c>(A)", "<c>(!A)", "<w>(1)", "<wt>(0.25)", "<a>(X, k=1)", '<c>(B,k="s")']
_NUMBER_RE = re.compile(r"-?[0-9]+(?:\.[0-9]+)?(?:[eE][+-]?[0-9]+)?")
_STRING_RE = re.compile(r'"(?:[^"\\]|\\.)*"')
_OPEN_RE = re.compile(r"<(?:sq|msq|sl|msl|neg|pl)>|<(?:pl|tt1|tt2|k)>\([^)]*\)")
# Tokens roughly as section 1 has them, and whatever else stands between them, one character at
# a time: the mutations work on the boundaries. A number before a name, so that ``1e5`` stays one.
_TOKEN_RE = re.compile(
    r"<[A-Za-z0-9_]*>"
    r"|-?[0-9]+(?:\.[0-9]+)?(?:[eE][+-]?[0-9]+)?"
    r"|[A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)*"
    r'|"(?:[^"\\\n]|\\.)*"'
    r"|#[^\n]*"
    r"|[ \t\r\n]+"
    r"|[\s\S]"
)
_WORD_START = frozenset('-0123456789"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz_')
# A leaf: its tag, then its parenthesised part (closed or not), or the bare name of ``<c>X``.
_LEAF_RE = re.compile(r"<(c|a|w|wt)>(?:\([^()<>]*\)?|[ \t]*!?[ \t]*[^\s<>()#,]*)")
_OPEN_TAG_RE = re.compile(r"<(?:sq|msq|sl|msl|neg|pl|tt1|tt2|k)>(?:\([^()<>]*\))?|<e>")

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
_TREE_FIELDS = ("sequence", "subtree")
_JSON_GAP_RE = re.compile(rb"[{\[:,]")


@dataclass
class Corpus:
    """The seeds, and what the mutations splice in: every leaf and every closed subtree of the
    stringBT seeds (short, valid inputs, one mutation away from the bugs of sections 1 and 2)."""

    texts: list[str]
    messages: list[bytes]
    pieces: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        if not self.pieces:
            self.pieces = _pieces(self.texts) or list(LEAVES)


def _pieces(texts: list[str]) -> list[str]:
    """Every leaf and every subtree up to 2,000 characters long, once each, in order."""
    found: dict[str, None] = {}
    for text in texts:
        for m in _LEAF_RE.finditer(text):
            found[m.group()] = None
        opened: list[int] = []
        for m in _OPEN_TAG_RE.finditer(text):
            if m.group() != "<e>":
                opened.append(m.start())
            elif opened:
                start = opened.pop()
                if m.end() - start <= 2_000:
                    found[text[start : m.end()]] = None
    return list(found)


def _repository_sbt_files() -> list[Path]:
    """Every ``.sbt`` file of a source checkout, outside hidden folders (``.venv``, ``.git``)
    and the top-level folders runs write into."""
    generated = {"build", "dist", "out", "results", "fuzz-failures", "keys", "ktbt-demo"}
    found: list[Path] = []
    for folder, dirs, files in os.walk(ROOT):
        top = Path(folder) == ROOT
        dirs[:] = sorted(d for d in dirs if not d.startswith(".") and not (top and d in generated))
        found += [Path(folder) / f for f in sorted(files) if f.endswith(".sbt")]
    return found


def seed_corpus() -> tuple[list[str], list[bytes]]:
    """stringBT seeds (the vectors' inputs and every ``.sbt`` file) and message seeds (the
    vectors' messages and a few valid ones)."""
    texts: list[str] = []
    vectors = ROOT / "spec" / "vectors"
    for name in ("valid", "invalid", "validation", "knowledge"):
        path = vectors / f"{name}.json"
        if path.exists():
            texts += [case["input"] for case in json.loads(path.read_text(encoding="utf-8"))]
    if vectors.is_dir():
        sbt_files = _repository_sbt_files()
    else:
        sbt_files = sorted(packaged("examples").rglob("*.sbt"))
    for path in sbt_files:
        texts.append(path.read_text(encoding="utf-8"))
    texts = [t for t in texts if len(t) <= MAX_TEXT] or ["<sq><c>(A)<a>(B)<e>"]
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
    path = vectors / "messages.json"
    if path.exists():
        for case in json.loads(path.read_text(encoding="utf-8")):
            messages.append(json.dumps(case["message"], ensure_ascii=False).encode())
    signing = vectors / "signing.json"
    if signing.exists():
        vector = json.loads(signing.read_text(encoding="utf-8"))
        messages.append(json.dumps(vector["response"], ensure_ascii=False).encode())
    return texts, messages


def load_corpus() -> Corpus:
    """The seeds of :func:`seed_corpus`, with the pieces cut from them."""
    texts, messages = seed_corpus()
    return Corpus(texts, messages)


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


def _rough(rng: random.Random, text: str, corpus: list[str]) -> str:
    """A mutation blind to tokens: a character or a span changed, deleted, repeated or spliced
    from another seed, nesting deepened."""
    n = len(text)
    i, j = sorted((rng.randint(0, n), rng.randint(0, n)))
    kind = rng.randrange(8)
    if kind == 0:
        return text[:i] + rng.choice(TOKENS) + text[i:]
    if kind == 1:
        return text[:i] + text[j:]
    if kind == 2:
        return text[:i] + text[i:j] * rng.randint(2, 4) + text[j:]
    if kind == 3 and n:
        c = chr(rng.choice((rng.randrange(32, 127), rng.randrange(0, 0x3000))))
        return text[:i] + c + text[i + 1 :]
    if kind == 4:
        other = rng.choice(corpus)
        a, b = sorted((rng.randint(0, len(other)), rng.randint(0, len(other))))
        return text[:i] + other[a:b] + text[j:]
    if kind == 5:
        depth = rng.choice((2, 8, 40, 200))
        return "<sq>" * depth + text + "<e>" * rng.choice((depth, depth - 1, 0))
    if kind == 6:
        return text[:i] + text[i:j].swapcase() + text[j:]
    return text[:i] + "".join(rng.choices(TOKENS, k=rng.randint(1, 6))) + text[j:]


def _draw(rng: random.Random, groups: list[list[str]]) -> str:
    """A group first, then a fragment of it (``LITERALS``)."""
    return rng.choice(rng.choice(groups))


def _rewrite_leaf(rng: random.Random, tag: str) -> str:
    """A leaf of the same kind around another literal: parenthesised or bare (section 2), with
    blanks, a comment or a ``!`` before the literal, something glued after it, and maybe an
    argument or no closing parenthesis."""
    word = _draw(rng, WORDS)
    if rng.random() < 0.5:
        word += _draw(rng, GLUE)
    bang = rng.choice(("", "", "!", " ! ")) if tag == "c" else rng.choice(("", "", "", "!"))
    if rng.random() < 0.5:
        blank = rng.choice(("", "", "", " ", "\n", "\t", " # c\n"))
        return f"<{tag}>{blank}{bang}{word}"
    close = rng.choice((")", ")", ")", "", f",k={_draw(rng, WORDS)})", ", k = 1 )"))
    return f"<{tag}>({bang}{word}{close}"


def _token_edit(rng: random.Random, text: str, pieces: list[str]) -> str:
    """One token-aware mutation (module docstring): the places bugs of sections 1 and 2 hide
    are where one token ends and the next begins. Leaves are rewritten twice as often as the
    rest is changed: they hold the literals."""
    kind = rng.randrange(9)
    if kind == 0 or kind == 8:  # a leaf rewritten
        leaves = list(_LEAF_RE.finditer(text))
        if leaves:
            m = rng.choice(leaves)
            return text[: m.start()] + _rewrite_leaf(rng, m.group(1)) + text[m.end() :]
        return text + _rewrite_leaf(rng, rng.choice(("c", "a", "w", "wt")))
    spans = [m.span() for m in _TOKEN_RE.finditer(text)]
    if not spans:
        return rng.choice(pieces)
    i, j = rng.choice(spans)
    if kind == 1:  # a literal swapped for another
        words = [(a, b) for a, b in spans if text[a] in _WORD_START]
        if words:
            i, j = rng.choice(words)
        return text[:i] + _draw(rng, WORDS) + text[j:]
    if kind == 2:  # a fragment glued after a token (or before it)
        glue = _draw(rng, GLUE) if rng.random() < 0.6 else _draw(rng, WORDS)
        if rng.random() < 0.75:
            return text[:j] + glue + text[j:]
        return text[:i] + glue + text[i:]
    if kind == 3:  # a tag swapped, added or dropped
        tags = [(a, b) for a, b in spans if text[a] == "<"]
        if tags:
            i, j = rng.choice(tags)
        choice = rng.randrange(3)
        if choice == 0:
            return text[:i] + rng.choice(TAGS) + text[j:]
        if choice == 1:
            return text[:i] + rng.choice(TAGS) + text[i:]
        return text[:i] + text[j:]
    if kind == 4:  # tokens dropped
        k = min(len(spans), spans.index((i, j)) + rng.randint(1, 3))
        return text[:i] + text[spans[k - 1][1] :]
    if kind == 5:  # a token repeated
        return text[:j] + text[i:j] * rng.randint(1, 3) + text[j:]
    if kind == 6:  # a leaf or subtree of a seed spliced in at a token boundary
        piece = rng.choice(pieces)
        if rng.random() < 0.5:
            return text[:j] + piece + text[j:]
        return text[:i] + piece + text[j:]
    # two tokens swapped
    a, b = rng.choice(spans)
    if a < i:
        a, b, i, j = i, j, a, b
    return text[:i] + text[a:b] + text[j:a] + text[i:j] + text[b:]


def mutate_text(
    rng: random.Random, text: str, corpus: list[str], pieces: list[str] | None = None
) -> str:
    """One to three token-aware mutations, or gentle ones, or one to four rough ones (module
    docstring): one family at a time, so that each family's inputs stay near valid text."""
    family = rng.random()
    if family < 0.5:
        pieces = pieces or _pieces([text]) or list(LEAVES)
        for _ in range(rng.randint(1, 3)):
            text = _token_edit(rng, text, pieces)
    elif family < 0.75:
        for _ in range(rng.randint(1, 3)):
            text = _gentle(rng, text)
    else:
        for _ in range(rng.randint(1, 4)):
            text = _rough(rng, text, corpus)
    return text[:MAX_TEXT]


def next_text(rng: random.Random, corpus: Corpus) -> str:
    """One text input: a seed, or a leaf or subtree cut from one, mutated. Nine times in ten the
    shortest of three draws is taken: the bugs of sections 1 and 2 show in a few tokens, and a
    short input is checked faster than a long one; the tenth draw is any seed, the limits of
    section 8 and the round trip of a whole file have their turn."""
    pool = corpus.pieces if rng.random() < 0.5 else corpus.texts
    draws = 3 if rng.random() < 0.9 else 1
    base = min((rng.choice(pool) for _ in range(draws)), key=len)
    return mutate_text(rng, base, corpus.texts, corpus.pieces)


def mutate_message(rng: random.Random, data: bytes, corpus: Corpus | None = None) -> bytes:
    """A wire message with fields changed (a stringBT field to a mutated text), JSON fragments
    spliced between its tokens, or its bytes mangled."""
    roll = rng.random()
    if roll < 0.5:
        try:
            obj = json.loads(data)
        except ValueError:
            obj = None
        if isinstance(obj, dict):
            for _ in range(rng.randint(1, 3)):
                key, value = rng.choice(MESSAGE_FIELDS)
                if corpus is not None and rng.random() < 0.4:
                    key, value = rng.choice(_TREE_FIELDS), next_text(rng, corpus)
                if value is None:
                    obj.pop(key, None)
                else:
                    obj[key] = value
            return json.dumps(obj, ensure_ascii=rng.random() < 0.5).encode("utf-8", "replace")
    raw = bytearray(data)
    if roll < 0.7:
        gaps = [m.end() for m in _JSON_GAP_RE.finditer(raw)]
        for _ in range(rng.randint(1, 3)):
            if not gaps:
                break
            i = rng.choice(gaps)
            raw[i:i] = _draw(rng, WORDS).encode("utf-8", "surrogatepass")
        return bytes(raw)
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
    """Every property of section "the parser", for one text. The fast parser runs first (it is
    the cheap one, and the one peers reach), and its tree is the one formatted and validated."""
    tree = None
    try:
        tree = parse(text)
        fast: object = tree.root
    except StringBTError as err:
        fast = (err.code, err.line, err.column)
    except Exception as exc:
        raise Failure(f"parse raised {type(exc).__name__}: {exc}") from exc
    try:
        reference: object = parse_reference(text).root
    except StringBTError as err:
        reference = (err.code, err.line, err.column)
    except Exception as exc:
        raise Failure(f"parse_reference raised {type(exc).__name__}: {exc}") from exc
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
    if tree is None:
        return
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
    """The decoder's properties (``spec/protocol.md`` section 1), for one received message."""
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


Emit = Callable[[tuple[Any, ...]], None]
"""How a worker tells the run what happened: ``("fail", line)``, ``("count", worker, inputs,
failures)`` now and then, and ``("done", worker, inputs, failures)`` at the end."""


def _worker_seed(seed: int, worker: int) -> int | str:
    """Worker 0 draws what a one-worker run with the same seed draws."""
    return seed if worker == 0 else f"{seed}w{worker}"


def _fuzz(
    worker: int,
    inputs: int | None,
    deadline: float | None,
    seed: int,
    out: Path,
    corpus: Corpus,
    emit: Emit,
    every: float,
) -> None:
    """One worker's loop: draw, check and save inputs until its share or the time is used up."""
    rng = random.Random(_worker_seed(seed, worker))
    registry = _fuzz_registry()
    failures = n = drawn = 0
    name = str(_worker_seed(seed, worker))
    last = time.perf_counter()
    seen: set[int] = set()  # what was checked already, by hash: a repeat is not counted again
    try:
        while inputs is None or n < inputs:
            drawn += 1
            if drawn & 63 == 0:
                now = time.perf_counter()
                if deadline is not None and now >= deadline:
                    break
                if now - last >= every:
                    last = now
                    emit(("count", worker, n, failures))
            text = None
            if rng.random() < 0.2:
                target, body = "message", mutate_message(rng, rng.choice(corpus.messages), corpus)
            else:
                text = next_text(rng, corpus)
                target, body = "text", text.encode("utf-8", "surrogatepass")
            key = hash((target, body))
            if key in seen:
                continue
            if len(seen) >= 1_000_000:
                seen.clear()
            seen.add(key)
            n += 1
            try:
                if text is None:
                    check_message(body)
                else:
                    check_text(text, registry)
            except Failure as error:
                failures += 1
                stem = f"{target}-{name}-{n}"
                _save(out, stem, body, error)
                emit(("fail", f"FAIL {stem}: {error}"))
    except KeyboardInterrupt:  # Ctrl-C ends the run early, and it says what it checked
        pass
    emit(("done", worker, n, failures))


def _save(out: Path, stem: str, body: bytes, error: Failure) -> None:
    """The input as it was checked (a text as UTF-8, lone surrogates kept), and what it broke."""
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{stem}.bin").write_bytes(body)
    (out / f"{stem}.txt").write_text(
        f"{error}\n\n{''.join(traceback.format_exception(error))}", encoding="utf-8"
    )


def _worker_main(
    worker: int,
    inputs: int | None,
    deadline: float | None,
    seed: int,
    out: Path,
    corpus: Corpus,
    results: Any,
    every: float,
) -> None:
    """A worker process: its loop, its events sent to the run through ``results``."""
    try:
        _fuzz(worker, inputs, deadline, seed, out, corpus, results.put, every)
    except BaseException as exc:  # the run must hear of it, or it would wait for this worker
        results.put(("fail", f"FAIL worker {worker}: {type(exc).__name__}: {exc}"))
        results.put(("done", worker, 0, 1))
        raise


def run(
    inputs: int | None,
    seed: int,
    out: Path,
    report: Callable[[str], None] = print,
    every: float = 30.0,
    *,
    seconds: float | None = None,
    workers: int = 1,
) -> int:
    """Fuzz ``inputs`` inputs, or for ``seconds`` (whichever ends first), on ``workers``
    processes; returns the number of failures (each saved under ``out``). Inputs per second
    are counted over the whole run, all workers together."""
    if inputs is None and seconds is None:
        raise ValueError("a run needs a number of inputs or a time")
    corpus = load_corpus()
    parse_reference("<a>(X)")  # the grammar is compiled once, before any worker starts
    workers = max(1, min(workers, inputs if inputs is not None else workers))
    if "fork" not in multiprocessing.get_all_start_methods():
        workers = 1
    shares: list[int | None] = [None] * workers
    if inputs is not None:
        shares = [inputs // workers + (k < inputs % workers) for k in range(workers)]
    bounds = []
    if inputs is not None:
        bounds.append(f"{inputs:,} inputs")
    if seconds is not None:
        bounds.append(f"{seconds:g} s")
    report(f"fuzzing for {' or '.join(bounds)}, seed {seed}, {_workers(workers)}")
    start = time.perf_counter()
    deadline = None if seconds is None else start + seconds
    done: dict[int, tuple[int, int]] = {}
    counts: dict[int, tuple[int, int]] = {}
    last = start

    def progress(event: tuple[Any, ...]) -> None:
        nonlocal last
        kind = event[0]
        if kind == "fail":
            report(event[1])
            return
        counts[event[1]] = (event[2], event[3])
        if kind == "done":
            done[event[1]] = (event[2], event[3])
        now = time.perf_counter()
        if kind == "count" and now - last >= every:
            last = now
            n = sum(c[0] for c in counts.values())
            failed = sum(c[1] for c in counts.values())
            report(f"{n:,} inputs, {n / (now - start):,.0f}/s, {failed} failures")

    if workers == 1:
        _fuzz(0, shares[0], deadline, seed, out, corpus, progress, every)
    else:
        context = multiprocessing.get_context("fork")  # the workers share the compiled corpus
        results = context.Queue()
        procs = [
            context.Process(
                target=_worker_main,
                args=(k, shares[k], deadline, seed, out, corpus, results, min(every, 1.0)),
                daemon=True,
            )
            for k in range(workers)
        ]
        for proc in procs:
            proc.start()
        interrupted = False
        while len(done) < workers:
            try:
                progress(results.get(timeout=1.0))
            except KeyboardInterrupt:  # the workers had it too: they stop and report
                if interrupted:
                    raise
                interrupted = True
            except queue.Empty:
                for k, proc in enumerate(procs):
                    if k not in done and not proc.is_alive() and proc.exitcode:
                        report(f"FAIL worker {k} ended with exit code {proc.exitcode}")
                        done[k] = counts.get(k, (0, 0))[0], counts.get(k, (0, 0))[1] + 1
        for proc in procs:
            proc.join()
    elapsed = time.perf_counter() - start
    n = sum(d[0] for d in done.values())
    failures = sum(d[1] for d in done.values())
    report(
        f"done: {n:,} inputs in {elapsed:,.1f} s ({n / elapsed:,.0f} inputs/s, "
        f"{_workers(workers)}), seed {seed}, {failures} failures"
    )
    return failures


def _workers(n: int) -> str:
    return f"{n} worker{'s' if n > 1 else ''}"


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on every platform
        return os.cpu_count() or 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ktbt_proto.tools.fuzz", description=__doc__)
    parser.add_argument("--seconds", type=float, default=None, help="how long to run")
    parser.add_argument(
        "--inputs", type=int, default=None, help="how many inputs (default: 100,000 if no time)"
    )
    parser.add_argument("--seed", type=int, default=None, help="random seed (default: time)")
    parser.add_argument(
        "--workers", type=int, default=None, help="worker processes (default: one per core)"
    )
    parser.add_argument("--out", type=Path, default=Path("fuzz-failures"))
    args = parser.parse_args(argv)
    seed = args.seed if args.seed is not None else int(time.time())
    inputs = args.inputs if args.inputs is not None or args.seconds else 100_000
    workers = args.workers if args.workers is not None else _cores()
    failures = run(
        inputs,
        seed,
        args.out,
        lambda line: print(line, flush=True),
        seconds=args.seconds,
        workers=workers,
    )
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
