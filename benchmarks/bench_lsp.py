"""How fast ``ktbt lsp`` answers a keystroke, beside ``ktbt check`` on the same text, same run.

Run with ``python -m benchmarks.bench_lsp`` (or ``python -m benchmarks`` for every module).
Prints Markdown tables and writes the numbers to ``benchmarks/results/lsp.json``.

The anchor is what ``ktbt check --vocabulary`` does for one file in process: parse, validate
against the vocabulary, look for warnings. Against it, on the 51-node reference tree after a
one-character edit:

- **server, in process**: what the server does for a ``didChange``: apply the incremental edit,
  check the text (the same three calls), and place each problem as an LSP range;
- **server, over stdio**: a real server process, from writing the ``didChange`` to reading its
  ``publishDiagnostics``, JSON and pipes included.

And a 1 MB file (the parse benchmark's): a one-character edit to its diagnostics over stdio,
which must stay under a second; the vocabulary is loaded once, never per keystroke.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Any

from lsprotocol import types as lsp

from ktbt_proto.items import find_warnings
from ktbt_proto.syntax import parse
from ktbt_proto.tools.lsp.diagnostics import check
from ktbt_proto.tools.lsp.document import Document
from ktbt_proto.tools.lsp.server import _diagnostic
from ktbt_proto.tools.vocabulary import read_vocabulary
from ktbt_proto.validate import find_problems

from .bench_parse import big_pretty, reference_compact
from .timing import interleaved, machine, markdown_table, write_json

ROUNDS = 2000
"""Interleaved rounds of the in-process cases."""
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


def stdio_edits(server: Stdio, path: Path, text: str, edits: int, word: str) -> list[int]:
    """Nanoseconds from each one-character edit (the last letter of ``word``'s first
    occurrence, to "b" and back) to its diagnostics."""
    uri = path.as_uri()
    server.notify(
        "textDocument/didOpen",
        {"textDocument": {"uri": uri, "languageId": "stringbt", "version": 1, "text": text}},
    )
    server.diagnostics(uri, 1)
    where = text.index(word) + len(word) - 1
    line = text.count("\n", 0, where)
    character = where - (text.rfind("\n", 0, where) + 1)
    samples = []
    for k in range(edits):
        version = k + 2
        letter = "b" if k % 2 == 0 else text[where]  # Act0b is known too: still valid
        start = time.perf_counter_ns()
        server.notify("textDocument/didChange", _edit(uri, version, line, character, 1, letter))
        server.diagnostics(uri, version)
        samples.append(time.perf_counter_ns() - start)
    server.notify("textDocument/didClose", {"textDocument": {"uri": uri}})
    return samples


def _median(samples: list[int]) -> float:
    ordered = sorted(samples)
    return ordered[len(ordered) // 2] / 1_000


def run(
    rounds: int = ROUNDS, stdio_rounds: int = STDIO_ROUNDS, big_edits: int = BIG_EDITS
) -> dict[str, Any]:
    text = reference_compact()
    with tempfile.TemporaryDirectory(prefix="ktbt-bench-lsp-") as folder:
        root = Path(folder)
        (root / "robot.toml").write_text(vocabulary(), encoding="utf-8")
        (root / "ktbt.toml").write_text('vocabulary = "robot.toml"\n', encoding="utf-8")
        registry = read_vocabulary(root / "robot.toml")
        document = Document((root / "tree.sbt").as_uri(), text)
        where = text.index("Act0a") + 4
        flip = {"a": "b", "b": "a"}

        def ktbt_check() -> object:
            tree = parse(document.text)
            return find_problems(tree, registry), find_warnings(tree)

        def server_in_process() -> object:
            letter = flip[document.text[where]]
            change = lsp.TextDocumentContentChangePartial(
                range=lsp.Range(start=lsp.Position(0, where), end=lsp.Position(0, where + 1)),
                text=letter,
            )
            document.apply([change], document.version + 1)
            checked = check(document.text, registry)
            return [_diagnostic(document, p) for p in checked.problems]

        stats = interleaved(
            {"ktbt check (in process)": ktbt_check, "server (in process)": server_in_process},
            rounds=rounds,
        )
        server = Stdio(root)
        try:
            over_stdio = stdio_edits(server, root / "tree.sbt", text, stdio_rounds, "Act0a")
            big = big_pretty()  # its names are not the reference tree's: checked without them
            bare = Path(tempfile.mkdtemp(prefix="ktbt-bench-lsp-bare-"))
            try:
                big_samples = stdio_edits(server, bare / "big.sbt", big, big_edits, "MoveTo")
            finally:
                bare.rmdir()
        finally:
            server.close()
    return {
        "machine": machine(),
        "reference_tree": {
            "characters": len(text),
            "check_us": stats["ktbt check (in process)"].median_us,
            "server_in_process_us": stats["server (in process)"].median_us,
            "server_stdio_us": _median(over_stdio),
            "rounds": rounds,
            "stdio_rounds": stdio_rounds,
        },
        "big_file": {"characters": len(big), "stdio_ms": _median(big_samples) / 1_000},
    }


def report(result: dict[str, Any]) -> str:
    ref, big = result["reference_tree"], result["big_file"]
    rows = [
        ["`ktbt check` (parse, validate, warnings), in process", f"{ref['check_us']:.1f}"],
        ["server: apply the edit, check, place the ranges", f"{ref['server_in_process_us']:.1f}"],
        ["server over stdio: didChange to publishDiagnostics", f"{ref['server_stdio_us']:.1f}"],
    ]
    return "\n".join(
        [
            f"## ktbt lsp: one keystroke ({result['machine']})",
            "",
            f"The 51-node reference tree ({ref['characters']} characters), median microseconds:",
            "",
            markdown_table(["case", "µs"], rows),
            "",
            f"A {big['characters']:,}-character file, one keystroke to its diagnostics over "
            f"stdio: {big['stdio_ms']:.0f} ms (median of {BIG_EDITS}).",
        ]
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_lsp")
    parser.add_argument("--rounds", type=int, default=ROUNDS, help="in-process rounds")
    parser.add_argument("--stdio-rounds", type=int, default=STDIO_ROUNDS, help="edits over stdio")
    parser.add_argument("--big-edits", type=int, default=BIG_EDITS, help="edits of the 1 MB file")
    parser.add_argument("--no-json", action="store_true", help="do not write results/lsp.json")
    args = parser.parse_args(argv)
    result = run(args.rounds, args.stdio_rounds, args.big_edits)
    print(report(result))
    if not args.no_json:
        path = write_json("lsp", result)
        print(f"\nWrote {path.relative_to(path.parents[2])}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
