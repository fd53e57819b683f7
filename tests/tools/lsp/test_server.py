"""``ktbt lsp`` over stdio, driven by a real LSP client (pytest-lsp): diagnostics as you type with
their codes, ranges and severities, formatting, completion, hover, symbols, folding, definition,
quick fixes and semantic tokens, against a project's vocabulary file, a Python registry, or
none; and hostile documents that must leave the server answering.

One server serves the whole module (it starts in about a second); each test opens documents of
its own. Every wait is for a message the server sends, bounded by a timeout."""

from __future__ import annotations

import asyncio
import shutil
import sys
from collections import defaultdict
from collections.abc import AsyncIterator, Sequence
from pathlib import Path
from typing import Any

import pytest
import pytest_lsp
from lsprotocol import types as lsp
from pytest_lsp import ClientServerConfig, LanguageClient, client_capabilities
from pytest_lsp.client import make_test_lsp_client

from ktbt_proto.formatter import format_tree
from ktbt_proto.syntax import parse
from tests.door_robot import FLAT, MEMORY, VOCABULARY

ROOT = Path(__file__).resolve().parents[3]
pytestmark = [pytest.mark.asyncio(loop_scope="module"), pytest.mark.network]
WAIT = 20.0
"""Seconds a test waits for the server at most (it answers in milliseconds)."""


class Published:
    """Every ``publishDiagnostics`` the client receives, kept with its version."""

    def __init__(self) -> None:
        self.by_uri: dict[str, list[lsp.PublishDiagnosticsParams]] = defaultdict(list)
        self.event = asyncio.Event()

    def record(self, params: lsp.PublishDiagnosticsParams) -> None:
        self.by_uri[params.uri].append(params)
        self.event.set()

    async def wait(self, uri: str, version: int | None) -> list[lsp.Diagnostic]:
        """The diagnostics of ``uri`` at ``version`` (any version when None), once they come."""

        async def arrived() -> list[lsp.Diagnostic]:
            while True:
                for params in self.by_uri[uri]:
                    if version is None or params.version == version:
                        return list(params.diagnostics)
                self.event.clear()
                await self.event.wait()

        return await asyncio.wait_for(arrived(), WAIT)


PUBLISHED: dict[int, Published] = {}


def make_client() -> LanguageClient:
    client = make_test_lsp_client()
    published = PUBLISHED[id(client)] = Published()
    features = client.protocol.fm.features
    original = features[lsp.TEXT_DOCUMENT_PUBLISH_DIAGNOSTICS]

    def publish(params: lsp.PublishDiagnosticsParams) -> None:
        published.record(params)
        original(params)

    features[lsp.TEXT_DOCUMENT_PUBLISH_DIAGNOSTICS] = publish
    return client


@pytest.fixture(scope="module")
def projects(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Four folders: ``file/`` whose ktbt.toml names a vocabulary file, ``python/`` whose
    pyproject.toml names a Python registry, ``broken/`` naming a file that is not there, and
    ``bare/`` with no settings."""
    root = tmp_path_factory.mktemp("projects")
    (root / "file").mkdir()
    (root / "file" / "door.toml").write_text(VOCABULARY, encoding="utf-8")
    (root / "file" / "ktbt.toml").write_text('vocabulary = "door.toml"\n', encoding="utf-8")
    (root / "python").mkdir()
    shutil.copy(ROOT / "tests" / "door_robot.py", root / "python" / "door_robot_lsp.py")
    (root / "python" / "pyproject.toml").write_text(
        '[tool.ktbt]\nvocabulary = "door_robot_lsp:door_registry"\n', encoding="utf-8"
    )
    (root / "broken").mkdir()
    (root / "broken" / "ktbt.toml").write_text('vocabulary = "gone.toml"\n', encoding="utf-8")
    (root / "bare").mkdir()
    return root


@pytest_lsp.fixture(  # type: ignore[untyped-decorator]
    scope="module",
    config=ClientServerConfig(
        server_command=[sys.executable, "-m", "ktbt_proto", "lsp"], client_factory=make_client
    ),
)
async def client(lsp_client: LanguageClient, projects: Path) -> AsyncIterator[None]:
    await lsp_client.initialize_session(
        lsp.InitializeParams(
            capabilities=client_capabilities("visual-studio-code"),
            root_uri=projects.as_uri(),
        )
    )
    yield
    await lsp_client.shutdown_session()


class Doc:
    """A document the test opens and edits, and what the server published for it."""

    def __init__(self, client: LanguageClient, path: Path, text: str) -> None:
        self.client, self.uri, self.text, self.version = client, path.as_uri(), text, 1
        self.ident = lsp.TextDocumentIdentifier(uri=self.uri)
        client.text_document_did_open(
            lsp.DidOpenTextDocumentParams(
                text_document=lsp.TextDocumentItem(
                    uri=self.uri, language_id="stringbt", version=1, text=text
                )
            )
        )

    @property
    def published(self) -> Published:
        return PUBLISHED[id(self.client)]

    async def diagnostics(self) -> list[lsp.Diagnostic]:
        return await self.published.wait(self.uri, self.version)

    def change(self, start: tuple[int, int], end: tuple[int, int], new: str) -> None:
        self.version += 1
        self.client.text_document_did_change(
            lsp.DidChangeTextDocumentParams(
                text_document=lsp.VersionedTextDocumentIdentifier(
                    uri=self.uri, version=self.version
                ),
                content_changes=[
                    lsp.TextDocumentContentChangePartial(
                        range=lsp.Range(start=lsp.Position(*start), end=lsp.Position(*end)),
                        text=new,
                    )
                ],
            )
        )

    def close(self) -> None:
        self.client.text_document_did_close(
            lsp.DidCloseTextDocumentParams(text_document=self.ident)
        )

    def at(self, word: str, plus: int = 0) -> lsp.Position:
        """The position (UTF-16) ``plus`` characters into the first ``word`` of the text."""
        offset = self.text.index(word) + plus
        line = self.text.count("\n", 0, offset)
        before = self.text[self.text.rfind("\n", 0, offset) + 1 : offset]
        return lsp.Position(line, len(before.encode("utf-16-le")) // 2)


def applied(text: str, edits: Sequence[lsp.TextEdit]) -> str:
    """The text with LSP edits applied (UTF-16 positions, lines at LF)."""
    lines = text.split("\n")

    def offset(position: lsp.Position) -> int:
        before = sum(len(line) + 1 for line in lines[: position.line])
        line = lines[position.line] if position.line < len(lines) else ""
        units = line.encode("utf-16-le")[: 2 * position.character].decode("utf-16-le")
        return min(before + len(units), len(text))

    spans = sorted((offset(e.range.start), offset(e.range.end), e.new_text) for e in edits)
    out, at = [], 0
    for start, end, new in spans:
        out += [text[at:start], new]
        at = end
    return "".join([*out, text[at:]])


def ranged(d: lsp.Diagnostic) -> tuple[Any, int, int, int, int]:
    r = d.range
    return d.code, r.start.line, r.start.character, r.end.line, r.end.character


async def test_diagnostics_have_their_code_range_and_severity(
    client: LanguageClient, projects: Path
) -> None:
    # The unknown action follows an "é" and an emoji on its line: UTF-16 counts the emoji twice.
    text = (
        "<sl>\n"
        "    <k>(new)\n"
        f"        {FLAT}\n"
        "    <e>\n"
        '    <sq><c>(HandleSeen, side="é😀")<a>(Fly)<e>\n'
        "<e>\n"
    )
    doc = Doc(client, projects / "file" / "door.sbt", text)
    found = await doc.diagnostics()
    rerun = text.index("<a>(GraspHandle)")
    assert [ranged(d) for d in found] == [
        (
            "SBT502",
            2,
            rerun - text.index("        <sq>"),
            2,
            rerun - text.index("        <sq>") + 16,
        ),
        ("SBT310", 4, 8, 4, 35),
        ("SBT306", 4, 39, 4, 42),
    ]
    assert [d.severity for d in found] == [
        lsp.DiagnosticSeverity.Warning,
        lsp.DiagnosticSeverity.Error,
        lsp.DiagnosticSeverity.Error,
    ]
    assert found[2].message == "unknown action 'Fly'" and found[2].source == "ktbt"
    assert "HandleSeen" in found[1].message and "side=" in found[1].message
    doc.close()


async def test_diagnostics_follow_incremental_edits_and_only_the_newest_is_published(
    client: LanguageClient, projects: Path
) -> None:
    doc = Doc(client, projects / "file" / "edit.sbt", "<sq>\n    <c>(DoorClosed)\n<e>\n")
    assert await doc.diagnostics() == []
    doc.change((1, 8), (1, 18), "DoorOpen")  # one edit: an unknown condition
    (unknown,) = await doc.diagnostics()
    assert ranged(unknown) == ("SBT305", 1, 8, 1, 16)
    for k in range(30):  # a burst of keystrokes: "x" typed thirty times after the name
        doc.change((1, 16 + k), (1, 16 + k), "x")
    (last,) = await doc.diagnostics()
    assert ranged(last) == ("SBT305", 1, 8, 1, 46)
    versions = [p.version or 0 for p in doc.published.by_uri[doc.uri]]
    assert versions == sorted(versions)  # never an older text's problems after a newer one's
    doc.change((1, 8), (1, 46), "DoorClosed")
    assert await doc.diagnostics() == []
    doc.close()


async def test_edits_inside_a_leaf_give_the_problems_of_the_whole_text(
    client: LanguageClient, projects: Path
) -> None:
    # The server reads only the edited leaf again (diagnostics.check): what it publishes is
    # what checking the whole text gives, keystroke after keystroke.
    doc = Doc(client, projects / "file" / "leaf.sbt", f"{MEMORY}\n")
    assert await doc.diagnostics() == []
    turn = doc.at("degrees=60", 10)
    doc.change((turn.line, turn.character), (turn.line, turn.character), "0")  # 600: too far
    (far,) = await doc.diagnostics()
    head = doc.at("<a>(TurnHandle")
    assert ranged(far) == (
        "SBT310",
        0,
        head.character,
        0,
        head.character + len("<a>(TurnHandle, degrees=600)"),
    )
    doc.change((turn.line, turn.character), (turn.line, turn.character + 1), "")
    assert await doc.diagnostics() == []
    push = doc.at("Push", 4)
    doc.change((push.line, push.character), (push.line, push.character), "y")
    (unknown,) = await doc.diagnostics()
    assert ranged(unknown) == ("SBT306", 0, push.character - 4, 0, push.character + 1)
    doc.close()


async def test_syntax_alone_without_a_vocabulary_and_one_line_when_it_will_not_load(
    client: LanguageClient, projects: Path
) -> None:
    bare = Doc(client, projects / "bare" / "t.sbt", "<sq><a>(Fly)<a>(Fly2)<e>\n<e>")
    (problem,) = await bare.diagnostics()  # names are not checked: no vocabulary
    assert ranged(problem) == ("SBT105", 1, 0, 1, 3)
    broken = Doc(client, projects / "broken" / "t.sbt", "<sq><a>(Fly)<e> <sq>")
    settings, syntax = await broken.diagnostics()
    assert settings.code == "ktbt-settings" and settings.range.start.line == 0
    assert str(projects / "broken" / "ktbt.toml") in settings.message
    assert "gone.toml" in settings.message
    assert syntax.code == "SBT106"
    bare.close()
    broken.close()


async def test_formatting_the_document_and_a_range(client: LanguageClient, projects: Path) -> None:
    text = "<sl>  # root\n<sq><c>(DoorClosed) <a>Push<e>\n    <a>(Push)\n<a>(Push)\n<e>"
    doc = Doc(client, projects / "file" / "fmt.sbt", text)
    options = lsp.FormattingOptions(tab_size=4, insert_spaces=True)
    edits = await client.text_document_formatting_async(
        lsp.DocumentFormattingParams(text_document=doc.ident, options=options)
    )
    assert edits
    assert applied(text, edits) == format_tree(parse(text))
    # The range touches line 1 only: its run of lines is formatted, line 3 is left as it is.
    edits = await client.text_document_range_formatting_async(
        lsp.DocumentRangeFormattingParams(
            text_document=doc.ident,
            range=lsp.Range(start=lsp.Position(1, 0), end=lsp.Position(1, 5)),
            options=options,
        )
    )
    assert edits and all(e.range.start.line == 1 for e in edits)
    assert applied(text, edits) == (
        "<sl>  # root\n    <sq>\n        <c>(DoorClosed)\n        <a>(Push)\n    <e>\n"
        "    <a>(Push)\n<a>(Push)\n<e>"
    )
    broken = Doc(client, projects / "file" / "fmt-broken.sbt", "<sq><a>(")
    assert not await client.text_document_formatting_async(
        lsp.DocumentFormattingParams(
            text_document=broken.ident,
            options=lsp.FormattingOptions(tab_size=4, insert_spaces=True),
        )
    )
    doc.close()
    broken.close()


async def complete(client: LanguageClient, doc: Doc, position: lsp.Position) -> list[str]:
    found = await client.text_document_completion_async(
        lsp.CompletionParams(text_document=doc.ident, position=position)
    )
    assert isinstance(found, lsp.CompletionList)
    return [item.label for item in found.items]


async def test_completion_of_tags_names_arguments_values_and_the_closing_e(
    client: LanguageClient, projects: Path
) -> None:
    text = "<sl>\n    <sq><c>(HandleSeen, side=)<a>(TurnHandle, )<a>()\n    <\n"
    doc = Doc(client, projects / "python" / "complete.sbt", text)
    tags = await complete(client, doc, doc.at("    <\n", 5))
    assert tags[0] == "<e>" and {"<sq>", "<k>", "<tt2>"} <= set(tags)
    assert await complete(client, doc, doc.at("<a>()", 4)) == ["GraspHandle", "Push", "TurnHandle"]
    assert await complete(client, doc, doc.at("TurnHandle, )", 12)) == ["degrees"]
    assert await complete(client, doc, doc.at("side=)", 5)) == ['"left"', '"right"']
    found = await client.text_document_completion_async(
        lsp.CompletionParams(text_document=doc.ident, position=doc.at("TurnHandle, )", 12))
    )
    assert isinstance(found, lsp.CompletionList)
    (degrees,) = found.items
    assert degrees.detail == "degrees: int, 1 <= degrees <= 90"
    assert degrees.text_edit is not None and degrees.text_edit.new_text == "degrees="
    doc.close()


async def test_hover_shows_signatures_docs_tags_and_placeholders(
    client: LanguageClient, projects: Path
) -> None:
    text = (
        "<sl>\n    <k>(prior)\n        <sq><c>(DoorClosed)<a>(TurnHandle, degrees=30)<e>\n"
        "    <e>\n<e>\n"
    )
    doc = Doc(client, projects / "file" / "hover.sbt", text)

    async def said(position: lsp.Position) -> str:
        found = await client.text_document_hover_async(
            lsp.HoverParams(text_document=doc.ident, position=position)
        )
        assert found is not None and isinstance(found.contents, lsp.MarkupContent)
        return found.contents.value

    turn = await said(doc.at("TurnHandle", 3))
    assert "action TurnHandle(degrees: int, 1 <= degrees <= 90)" in turn
    assert "Turn the grasped handle, 30 degrees a tick." in turn
    assert "reactive" in await said(doc.at("<sl>", 1))
    assert "knowledge this robot was built with" in await said(doc.at("prior", 1))
    assert "blackboard flag" in await said(doc.at("DoorClosed"))
    doc.close()


async def test_symbols_folding_and_definition(client: LanguageClient, projects: Path) -> None:
    text = (
        "<sl>\n    <k>(new)\n        <sq>\n            <c>(DoorClosed)\n"
        "            <a>(Push)\n        <e>\n    <e>\n<e>\n"
    )
    doc = Doc(client, projects / "file" / "outline.sbt", text)
    symbols = await client.text_document_document_symbol_async(
        lsp.DocumentSymbolParams(text_document=doc.ident)
    )
    assert symbols is not None
    (root,) = symbols
    assert isinstance(root, lsp.DocumentSymbol) and root.children is not None
    (placeholder,) = root.children
    assert placeholder.name == "<k>(new)" and placeholder.children is not None
    assert placeholder.children[0].name == "item DoorClosed"
    assert placeholder.children[0].range.end.line == 5
    folds = await client.text_document_folding_range_async(
        lsp.FoldingRangeParams(text_document=doc.ident)
    )
    assert folds is not None
    assert [(f.start_line, f.end_line) for f in folds] == [(0, 7), (1, 6), (2, 5)]
    place = await client.text_document_definition_async(
        lsp.DefinitionParams(text_document=doc.ident, position=doc.at("Push", 1))
    )
    assert isinstance(place, lsp.Location)
    assert place.uri == (projects / "file" / "door.toml").as_uri()
    assert VOCABULARY.splitlines()[place.range.start.line] == "[actions.Push]"
    python = Doc(client, projects / "python" / "outline.sbt", text)
    place = await client.text_document_definition_async(
        lsp.DefinitionParams(text_document=python.ident, position=python.at("Push", 1))
    )
    assert isinstance(place, lsp.Location)
    source = projects / "python" / "door_robot_lsp.py"
    assert place.uri == source.as_uri()
    line = source.read_text(encoding="utf-8").splitlines()[place.range.start.line]
    assert line.strip() == "def push(bb: kp.Blackboard) -> kp.Status:"
    doc.close()
    python.close()


async def fixes(client: LanguageClient, doc: Doc, problem: lsp.Diagnostic) -> list[lsp.CodeAction]:
    found = await client.text_document_code_action_async(
        lsp.CodeActionParams(
            text_document=doc.ident,
            range=problem.range,
            context=lsp.CodeActionContext(diagnostics=[problem]),
        )
    )
    assert found is not None
    return [a for a in found if isinstance(a, lsp.CodeAction)]


async def test_quick_fixes_for_the_rerun_trap_and_a_missing_e(
    client: LanguageClient, projects: Path
) -> None:
    doc = Doc(client, projects / "file" / "fix.sbt", FLAT)
    (warning,) = await doc.diagnostics()
    (action,) = await fixes(client, doc, warning)
    assert action.kind == lsp.CodeActionKind.QuickFix and action.is_preferred
    assert action.edit is not None and action.edit.changes is not None
    assert applied(FLAT, list(action.edit.changes[doc.uri])) == MEMORY
    unclosed = "<sl>\n    <sq>\n        <a>(Push)"
    open_doc = Doc(client, projects / "file" / "unclosed.sbt", unclosed)
    (problem,) = await open_doc.diagnostics()
    assert problem.code == "SBT104"
    (action,) = await fixes(client, open_doc, problem)
    assert action.edit is not None and action.edit.changes is not None
    closed = applied(unclosed, list(action.edit.changes[open_doc.uri]))
    assert closed == unclosed + "\n    <e>\n<e>\n"
    doc.close()
    open_doc.close()


async def test_semantic_tokens_follow_the_grammar(client: LanguageClient, projects: Path) -> None:
    text = '<sq><c>(!HandleSeen, side="é") <a>(Push) # done\n<e>\n'
    doc = Doc(client, projects / "file" / "tokens.sbt", text)
    tokens = await client.text_document_semantic_tokens_full_async(
        lsp.SemanticTokensParams(text_document=doc.ident)
    )
    assert isinstance(tokens, lsp.SemanticTokens)
    from ktbt_proto.tools.lsp.navigation import TOKEN_TYPES

    data = tokens.data
    kinds = [TOKEN_TYPES[data[i + 3]] for i in range(0, len(data), 5)]
    assert kinds == [
        "keyword", "keyword", "operator", "variable", "parameter", "string", "keyword",
        "function", "comment", "keyword",
    ]  # fmt: skip
    assert data[5 * 5 + 2] == 3  # "é" quoted: three UTF-16 units
    doc.close()


def _hostile() -> dict[str, str]:
    import json

    found = json.loads((ROOT / "tests" / "data" / "fuzz" / "inputs.json").read_text("utf-8"))
    texts = {f"fuzz-{k}": case["input"] for k, case in enumerate(found["texts"][:20])}
    return texts | {
        "huge": "<sq>" + "<a>(Push)" * 500_000 + "<e>",  # 4.5 MB: past the size limit
        "deep": "<sq>" * 100_000,
        "surrogates": '<sq><a>(Say, text="\ud800")\udfff<e>',
        "nul": "\x00<sq>\x00",
        "half-typed": "<sq><c>(!, side=, <a>(TurnHandle, degrees=<k>(",
    }


async def every_request(client: LanguageClient, ident: lsp.TextDocumentIdentifier) -> None:
    """Ask the server everything about a document: each request must be answered."""
    await client.text_document_document_symbol_async(lsp.DocumentSymbolParams(text_document=ident))
    await client.text_document_folding_range_async(lsp.FoldingRangeParams(text_document=ident))
    await client.text_document_semantic_tokens_full_async(
        lsp.SemanticTokensParams(text_document=ident)
    )
    await client.text_document_completion_async(
        lsp.CompletionParams(text_document=ident, position=lsp.Position(0, 7))
    )
    await client.text_document_hover_async(
        lsp.HoverParams(text_document=ident, position=lsp.Position(0, 1))
    )
    await client.text_document_formatting_async(
        lsp.DocumentFormattingParams(
            text_document=ident, options=lsp.FormattingOptions(tab_size=4, insert_spaces=True)
        )
    )


async def test_hostile_documents_get_diagnostics_or_nothing_and_the_server_keeps_answering(
    client: LanguageClient, projects: Path
) -> None:
    for name, text in _hostile().items():
        doc = Doc(client, projects / "file" / f"hostile-{name}.sbt", text)
        await doc.diagnostics()
        await asyncio.wait_for(every_request(client, doc.ident), WAIT)
        doc.close()
    alive = Doc(client, projects / "file" / "alive.sbt", "<sq><a>(Fly)<e>")
    (problem,) = await alive.diagnostics()
    assert problem.code == "SBT306"
    alive.close()
