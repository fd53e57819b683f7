"""How fast ``ktbt lsp`` answers a keystroke, beside ``ktbt check`` on the same text, same run.

Run with ``python -m benchmarks.bench_lsp`` (or ``python -m benchmarks`` for every module).
Prints Markdown tables and writes the numbers to ``benchmarks/results/lsp.json``.

The anchor is what ``ktbt check --vocabulary`` does for one file in process: parse, validate
against the vocabulary, look for warnings, on the document's text as it is at that moment.
Against it, on the 51-node reference tree:

- **server, in process**: what the server does for a ``didChange``, the same calls in the same
  order: apply the incremental edit, take how much of the text it left alone, find the
  document's vocabulary (``KtbtServer.known``: a ``stat`` of each settings file and of the
  vocabulary, never a read while they are unchanged), check the text from the previous check
  (``diagnostics.check``: the one leaf read again and validated when the edit is inside its
  tag or parentheses, the container's kind swapped and the tree validated again when it is
  inside a container's tag, the nodes moved when it is blanks, the comment's text replaced when
  it is inside one, the whole text otherwise), and turn each problem into an LSP diagnostic;
- **server, over stdio**: a real server process, from writing the ``didChange`` to reading its
  ``publishDiagnostics``, JSON and pipes included.

Nine keystrokes, each against ``ktbt check`` of the very text the server checks:

- **a letter changed in a name** (``Act0a`` to ``Act0b`` and back, compact form): the target's
  measure (at most one ``ktbt check``);
- **a letter typed into a name, then deleted** (``Act0a`` to ``Act0ax`` and back, pretty form):
  a name's length changes, the nodes on other lines keep their positions;
- **the same in the compact form**: the nodes after it, all on its one line, move;
- **a letter changed in a tag** (``<sq>`` to ``<sl>`` and back): a sequence becomes a selector,
  the tree is validated again without being read;
- **a blank typed into an indentation, then deleted** (pretty form): the nodes after it on its
  line move;
- **a line break typed, then deleted** (between two leaves, compact form): the nodes after it
  move to other lines;
- **a letter typed into a comment, then deleted** (the pretty form under a comment line): the
  comment's new text put in the tree;
- **a leaf's tag changed** (``<c>`` to ``<a>`` and back): the leaf read again;
- **a leaf commented out, then back** (a ``#`` typed before it, pretty form): the whole text is
  checked again, what any other edit costs (a ``<e>``, a text that does not parse...).

The in-process cases are measured ``--runs`` times (interleaved rounds each); the figures are
the medians of the runs' medians, with each run's ratio. And a 1 MB file (the parse
benchmark's): a one-character edit to its diagnostics over stdio, which must stay under a
second; the vocabulary is loaded once, never per keystroke.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO, Any

from lsprotocol import types as lsp

from ktbt_proto.formatter import format_tree
from ktbt_proto.items import find_warnings
from ktbt_proto.syntax import parse
from ktbt_proto.tools.lsp.diagnostics import check
from ktbt_proto.tools.lsp.document import Document
from ktbt_proto.tools.lsp.server import KtbtServer, _diagnostic
from ktbt_proto.validate import SupportsNames, find_problems

from .bench_parse import big_pretty, reference_compact
from .timing import interleaved, machine, markdown_table, write_json

ROUNDS = 2000
"""Interleaved rounds of the in-process cases, per run."""
RUNS = 5
"""Runs of the in-process cases."""
STDIO_ROUNDS = 300
"""Edits timed over stdio on the reference tree."""
BIG_EDITS = 5
"""Edits timed over stdio on the 1 MB file."""


def vocabulary() -> str:
    """The reference tree's names as a vocabulary file (a name with a typo is unknown)."""
    conditions = [f"Cond{i}{s}" for i in range(10) for s in "ab"]
    actions = [f"Act{i}{s}" for i in range(10) for s in "ab"]
    return f"conditions = {json.dumps(conditions)}\nactions = {json.dumps(actions)}\n"


class Stdio:
    """A ``ktbt lsp`` process and the few messages this benchmark sends it."""

    def __init__(self, root: Path) -> None:
        self.process = subprocess.Popen(
            [sys.executable, "-m", "ktbt_proto", "lsp"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            cwd=root,
        )
        self.ids = 0
        self.request("initialize", {"processId": os.getpid(), "capabilities": {}})
        self.notify("initialized", {})

    @property
    def _in(self) -> IO[bytes]:
        if self.process.stdin is None:
            raise RuntimeError("no stdin")
        return self.process.stdin

    def _send(self, message: dict[str, Any]) -> None:
        body = json.dumps(message).encode("utf-8")
        self._in.write(b"Content-Length: %d\r\n\r\n" % len(body) + body)
        self._in.flush()

    def read(self) -> dict[str, Any]:
        out = self.process.stdout
        if out is None:
            raise RuntimeError("no stdout")
        length = 0
        while (line := out.readline().strip()) != b"":
            if line.lower().startswith(b"content-length:"):
                length = int(line.split(b":")[1])
        message: dict[str, Any] = json.loads(out.read(length))
        return message

    def notify(self, method: str, params: dict[str, Any]) -> None:
        self._send({"jsonrpc": "2.0", "method": method, "params": params})

    def request(self, method: str, params: dict[str, Any] | None) -> Any:
        self.ids += 1
        self._send({"jsonrpc": "2.0", "id": self.ids, "method": method, "params": params})
        while True:
            message = self.read()
            if message.get("id") == self.ids:
                return message.get("result")

    def diagnostics(self, uri: str, version: int) -> list[Any]:
        while True:
            message = self.read()
            params = message.get("params") or {}
            if (
                message.get("method") == "textDocument/publishDiagnostics"
                and params.get("uri") == uri
                and params.get("version") == version
            ):
                return list(params["diagnostics"])

    def close(self) -> None:
        self.request("shutdown", None)
        self.notify("exit", {})
        self.process.wait(timeout=10)


def _edit(uri: str, version: int, line: int, character: int, old: int, new: str) -> Any:
    return {
        "textDocument": {"uri": uri, "version": version},
        "contentChanges": [
            {
                "range": {
                    "start": {"line": line, "character": character},
                    "end": {"line": line, "character": character + old},
                },
                "text": new,
            }
        ],
    }


def stdio_edits(
    server: Stdio, path: Path, text: str, edits: int, where: int, letter: str
) -> list[int]:
    """Nanoseconds from each one-character edit (the character at ``where`` changed to
    ``letter`` and back) to its diagnostics."""
    uri = path.as_uri()
    server.notify(
        "textDocument/didOpen",
        {"textDocument": {"uri": uri, "languageId": "stringbt", "version": 1, "text": text}},
    )
    server.diagnostics(uri, 1)
    line = text.count("\n", 0, where)
    character = where - (text.rfind("\n", 0, where) + 1)
    samples = []
    for k in range(edits):
        version = k + 2
        new = letter if k % 2 == 0 else text[where]
        start = time.perf_counter_ns()
        server.notify("textDocument/didChange", _edit(uri, version, line, character, 1, new))
        server.diagnostics(uri, version)
        samples.append(time.perf_counter_ns() - start)
    server.notify("textDocument/didClose", {"textDocument": {"uri": uri}})
    return samples


def _median(samples: list[int]) -> float:
    ordered = sorted(samples)
    return ordered[len(ordered) // 2] / 1_000


class Keystrokes:
    """One open document that a letter at ``where`` is changed in, back and forth, as the
    server does it (the same calls as ``KtbtServer._check`` and ``publish``)."""

    def __init__(self, path: Path, text: str, where: int, letters: str) -> None:
        self.ls = KtbtServer()
        self.document = Document(path.as_uri(), text)
        known, _ = self.ls.known(self.document.uri)
        if known is None:
            raise RuntimeError(f"no vocabulary for {path}")
        self.registry: SupportsNames = known.registry
        self.where, self.letters = where, letters
        self.checked = check(text, self.registry, None, self.document.take_edits())
        self.typed = False
        self.stages: dict[str, list[int]] = {}

    def change(self) -> lsp.TextDocumentContentChangePartial:
        """The next keystroke: ``letters`` is two letters, one replaced by the other; or one
        letter, typed at ``where`` then deleted."""
        self.typed = not self.typed
        line = self.document.text.count("\n", 0, self.where)
        character = self.where - (self.document.text.rfind("\n", 0, self.where) + 1)
        at = lsp.Position(line, character)
        if len(self.letters) == 1:
            after = lsp.Position(line + 1, 0) if self.letters == "\n" else None
            end = at if self.typed else after or lsp.Position(line, character + 1)
            new = self.letters if self.typed else ""
        else:
            end = lsp.Position(line, character + 1)
            new = self.letters[self.typed]
        return lsp.TextDocumentContentChangePartial(range=lsp.Range(start=at, end=end), text=new)

    def registry_now(self) -> SupportsNames | None:
        """The vocabulary as the server finds it for each check (a ``stat`` or two)."""
        known, _ = self.ls.known(self.document.uri)
        return known.registry if known is not None else None

    def server(self, change: lsp.TextDocumentContentChangePartial) -> list[lsp.Diagnostic]:
        document = self.document
        document.apply([change], document.version + 1)
        same = document.take_edits()
        self.checked = check(document.text, self.registry_now(), self.checked, same)
        return [_diagnostic(document, p) for p in self.checked.problems]

    def staged(self) -> None:
        """:meth:`server` for :meth:`change`, each stage timed on its own: where the time of a
        keystroke goes."""
        clock = time.perf_counter_ns
        t0 = clock()
        change = self.change()
        t1 = clock()
        document = self.document
        document.apply([change], document.version + 1)
        same = document.take_edits()
        t2 = clock()
        registry = self.registry_now()
        t3 = clock()
        self.checked = check(document.text, registry, self.checked, same)
        t4 = clock()
        [_diagnostic(document, p) for p in self.checked.problems]
        t5 = clock()
        stages = (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4)
        for stage, took in zip(STAGES, stages, strict=True):
            self.stages.setdefault(stage, []).append(took)

    def ktbt_check(self) -> object:
        tree = parse(self.document.text)
        return find_problems(tree, self.registry), find_warnings(tree)


def _cases(
    keys: dict[str, Keystrokes], staged: dict[str, Keystrokes]
) -> dict[str, Callable[[], object]]:
    """For each keystroke, ``ktbt check`` of the document's text and the server's answer to
    the keystroke, the change included (building it stands for pygls reading the JSON); and
    the same answer on a document of its own, stage by stage."""
    cases: dict[str, Callable[[], object]] = {}
    for name, key in keys.items():
        cases[f"{name}: ktbt check"] = key.ktbt_check
        cases[f"{name}: server"] = lambda key=key: key.server(key.change())  # type: ignore[misc]
        cases[f"{name}: stages"] = staged[name].staged
    return cases


STAGES = (
    "the change built (pygls's reading of the JSON)",
    "the edit applied, the unchanged start and end taken",
    "the vocabulary found (a stat of the settings and of the vocabulary)",
    "the check, from the previous one",
    "the problems as LSP diagnostics",
)


KEYSTROKES = (
    "a letter changed in a name",
    "a letter typed into a name",
    "a letter typed into a name, compact form",
    "a letter changed in a tag",
    "a blank typed into an indentation",
    "a line break typed",
    "a letter typed into a comment",
    "a leaf's tag changed",
    "a leaf commented out",
)


def run(
    rounds: int = ROUNDS,
    stdio_rounds: int = STDIO_ROUNDS,
    big_edits: int = BIG_EDITS,
    runs: int = RUNS,
) -> dict[str, Any]:
    text = reference_compact()
    pretty = format_tree(parse(text), "pretty")
    commented = f"# The reference tree\n{pretty}"
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="ktbt-bench-lsp-") as folder:
        root = Path(folder)
        (root / "robot.toml").write_text(vocabulary(), encoding="utf-8")
        (root / "ktbt.toml").write_text('vocabulary = "robot.toml"\n', encoding="utf-8")
        tree = root / "tree.sbt"  # the vocabulary as ktbt lsp finds it: ktbt.toml names it

        def keystrokes() -> dict[str, Keystrokes]:
            return {
                KEYSTROKES[0]: Keystrokes(tree, text, text.index("Act0a") + 4, "ab"),
                KEYSTROKES[1]: Keystrokes(tree, pretty, pretty.index("Act0a") + 5, "x"),
                KEYSTROKES[2]: Keystrokes(tree, text, text.index("Act0a") + 5, "x"),
                KEYSTROKES[3]: Keystrokes(tree, text, text.index("<sq>", 4) + 2, "ql"),
                KEYSTROKES[4]: Keystrokes(tree, pretty, pretty.index("<a>(Act0a)") - 2, " "),
                KEYSTROKES[5]: Keystrokes(tree, text, text.index("<a>(Act0a)"), "\n"),
                KEYSTROKES[6]: Keystrokes(tree, commented, commented.index("tree"), "x"),
                KEYSTROKES[7]: Keystrokes(tree, text, text.index("<c>(Cond0a)") + 1, "ca"),
                KEYSTROKES[8]: Keystrokes(tree, pretty, pretty.index("<a>(Act0a)"), "#"),
            }

        keys, staged = keystrokes(), keystrokes()
        measured = [interleaved(_cases(keys, staged), rounds=rounds) for _ in range(runs)]
        server = Stdio(root)
        try:
            in_act = text.index("Act0a") + 4  # Act0b is known too: still valid
            over_stdio = stdio_edits(server, root / "tree.sbt", text, stdio_rounds, in_act, "b")
            big = big_pretty()  # its names are not the reference tree's: checked without them
            bare = Path(tempfile.mkdtemp(prefix="ktbt-bench-lsp-bare-"))
            try:
                in_name = big.index("MoveTo") + 5
                big_name = stdio_edits(server, bare / "big.sbt", big, big_edits, in_name, "b")
                in_tag = big.index("<sq>") + 2
                big_tag = stdio_edits(server, bare / "big.sbt", big, big_edits, in_tag, "l")
            finally:
                bare.rmdir()
        finally:
            server.close()
    figures: dict[str, Any] = {}
    for name in KEYSTROKES:
        checks = [m[f"{name}: ktbt check"].median_us for m in measured]
        servers = [m[f"{name}: server"].median_us for m in measured]
        figures[name] = {
            "check_us": statistics.median(checks),
            "server_us": statistics.median(servers),
            "ratios": [round(s / c, 3) for s, c in zip(servers, checks, strict=True)],
            "ratio": statistics.median(s / c for s, c in zip(servers, checks, strict=True)),
            "stages_us": {
                stage: _median(samples) for stage, samples in staged[name].stages.items()
            },
        }
    return {
        "machine": machine(),
        "load_average": [round(x, 2) for x in (*load_before, *os.getloadavg())],
        "reference_tree": {
            "characters": len(text),
            "keystrokes": figures,
            "server_stdio_us": _median(over_stdio),
            "rounds": rounds,
            "runs": runs,
            "stdio_rounds": stdio_rounds,
        },
        "big_file": {
            "characters": len(big),
            "name_stdio_ms": _median(big_name) / 1_000,
            "tag_stdio_ms": _median(big_tag) / 1_000,
            "edits": big_edits,
        },
    }


def report(result: dict[str, Any]) -> str:
    ref, big = result["reference_tree"], result["big_file"]
    rows = []
    for name, key in ref["keystrokes"].items():
        ratios = ", ".join(f"{r:.2f}" for r in key["ratios"])
        rows.append(
            [
                name,
                f"{key['check_us']:.1f}",
                f"{key['server_us']:.1f}",
                f"**{key['ratio']:.2f}x** ({ratios})",
            ]
        )
    load = result["load_average"]
    return "\n".join(
        [
            f"## ktbt lsp: one keystroke ({result['machine']})",
            "",
            f"The 51-node reference tree ({ref['characters']} characters), medians of "
            f"{ref['runs']} runs of {ref['rounds']} interleaved rounds, microseconds (load "
            f"average {load[0]:.1f} before, {load[3]:.1f} after):",
            "",
            markdown_table(
                ["keystroke", "`ktbt check`, same text", "server", "server / check (each run)"],
                rows,
            ),
            "",
            "Where the server's time goes (median µs of each stage, timed on its own):",
            "",
            markdown_table(
                ["stage", *KEYSTROKES],
                [
                    [stage, *(f"{k['stages_us'][stage]:.1f}" for k in ref["keystrokes"].values())]
                    for stage in STAGES
                ],
            ),
            "",
            f"Over stdio (didChange to publishDiagnostics, a letter changed in a name): "
            f"{ref['server_stdio_us']:.0f} µs (median of {ref['stdio_rounds']}).",
            "",
            f"A {big['characters']:,}-character file, one keystroke to its diagnostics over "
            f"stdio (median of {big['edits']}): {big['name_stdio_ms']:.1f} ms for a letter in a "
            f"name, {big['tag_stdio_ms']:.0f} ms for a letter in a tag (the whole tree validated).",
        ]
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_lsp")
    parser.add_argument("--rounds", type=int, default=ROUNDS, help="in-process rounds")
    parser.add_argument("--stdio-rounds", type=int, default=STDIO_ROUNDS, help="edits over stdio")
    parser.add_argument("--big-edits", type=int, default=BIG_EDITS, help="edits of the 1 MB file")
    parser.add_argument("--runs", type=int, default=RUNS, help="runs of the in-process cases")
    parser.add_argument("--no-json", action="store_true", help="do not write results/lsp.json")
    args = parser.parse_args(argv)
    result = run(args.rounds, args.stdio_rounds, args.big_edits, args.runs)
    print(report(result))
    if not args.no_json:
        path = write_json("lsp", result)
        print(f"\nWrote {path.relative_to(path.parents[2])}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
