"""The language server: pygls over stdio, one handler per LSP feature, each a thin call into the
modules beside it (see the package's docstring for which does what).

Three rules hold for every handler:

- **Nothing a document holds can stop the server.** Whatever text a client sends (megabytes,
  nesting past every limit, lone surrogates, half-typed heads), the language's own functions
  answer with a ``StringBTError`` or a tree; and a handler that raises all the same is caught,
  logged on stderr with its traceback, and answered with nothing (no diagnostics, no edits),
  as a robot treats a message its reader cannot read (spec/protocol.md section 2.1: a reader
  that raises is a refusal, not a crash).
- **The editor never waits on a check.** Changes are applied at once (incremental sync); the
  check (parse, validation, warnings) runs on a worker thread, at most one per document at a
  time, started at once when none is running. Changes that come while one runs are not
  queued: when it ends on an older version than the document now has, its result is dropped
  and the newest text alone is checked next, so a burst of keystrokes costs at most two checks
  and the last one answers the text as it is.
- **One vocabulary per document, loaded once** (:class:`.vocabulary.Vocabularies`).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from functools import wraps
from pathlib import Path
from typing import ParamSpec, TypeVar

from lsprotocol import types as lsp
from pygls.lsp.server import LanguageServer
from pygls.uris import from_fs_path, to_fs_path

from ktbt_proto import __version__
from ktbt_proto.errors import ErrorCode
from ktbt_proto.limits import DEFAULT_LIMITS
from ktbt_proto.tools.lsp import assist, navigation
from ktbt_proto.tools.lsp.diagnostics import Checked, Problem, check
from ktbt_proto.tools.lsp.document import UTF16, Document
from ktbt_proto.tools.lsp.formatting import Edit, close_open_nodes, format_edits, memory_form
from ktbt_proto.tools.lsp.outline import Outline, read
from ktbt_proto.tools.lsp.vocabulary import Known, Vocabularies

log = logging.getLogger("ktbt.lsp")

SOURCE = "ktbt"
DEBOUNCE = 0.0
"""Seconds a check waits after a change for more to come: none by default, since changes that
come while a check runs are folded into the next one anyway (``ktbt lsp`` answers a keystroke
in the time of one check)."""
CONFIGURATION = "ktbt-settings"
"""The code of the diagnostic saying a vocabulary could not be loaded."""

P = ParamSpec("P")
R = TypeVar("R")


def guarded(handler: Callable[P, R]) -> Callable[P, R | None]:
    """A handler that answers nothing (logged) instead of raising (see the module's
    docstring)."""

    @wraps(handler)
    def run(*args: P.args, **kwargs: P.kwargs) -> R | None:
        try:
            return handler(*args, **kwargs)
        except Exception:
            log.exception("ktbt lsp: %s failed; answered with nothing", handler.__name__)
            return None

    return run


class KtbtServer(LanguageServer):
    """The server's state: open documents, their latest check and outline, the vocabularies."""

    def __init__(self, vocabulary: str | None = None, debounce: float = DEBOUNCE) -> None:
        super().__init__(
            "ktbt", __version__, text_document_sync_kind=lsp.TextDocumentSyncKind.Incremental
        )
        self.documents: dict[str, Document] = {}
        self.vocabularies = Vocabularies(vocabulary)
        self.debounce = debounce
        self._checks: dict[str, asyncio.Task[None]] = {}
        self._outlines: dict[str, tuple[int, Outline]] = {}
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="ktbt-check")

    # -- documents --------------------------------------------------------------------------

    @property
    def encoding(self) -> str:
        try:
            chosen = self.workspace.position_encoding
        except Exception:  # before initialize
            return UTF16
        return str(getattr(chosen, "value", chosen) or UTF16)  # the enum's value: "utf-16"

    def document(self, uri: str) -> Document | None:
        return self.documents.get(uri)

    def outline(self, document: Document) -> Outline:
        cached = self._outlines.get(document.uri)
        if cached is not None and cached[0] == document.version:
            return cached[1]
        # Past the size limit the text is not stringBT (SBT201, spec/stringbt.md section 8):
        # it gets that one diagnostic, and no outline is read of its megabytes.
        too_large = len(document.text) > DEFAULT_LIMITS.max_size
        outline = read("" if too_large else document.text)
        self._outlines[document.uri] = (document.version, outline)
        return outline

    def known(self, uri: str) -> tuple[Known | None, str | None]:
        path = to_fs_path(uri)
        return self.vocabularies.for_path(Path(path) if path else None)

    # -- checking ---------------------------------------------------------------------------

    def schedule(self, uri: str, pause: float) -> None:
        """Check ``uri`` soon, unless a check of it is already waiting or running (that one
        will see the newest text)."""
        running = self._checks.get(uri)
        if running is not None and not running.done():
            return
        self._checks[uri] = asyncio.ensure_future(self._check(uri, pause))

    async def _check(self, uri: str, pause: float) -> None:
        loop = asyncio.get_running_loop()
        while True:
            await asyncio.sleep(pause)
            pause = self.debounce
            document = self.documents.get(uri)
            if document is None:
                return
            version, text = document.version, document.text
            try:
                known, reason = self.known(uri)
                registry = known.registry if known is not None else None
                checked = await loop.run_in_executor(self._worker, check, text, registry)
            except Exception:
                log.exception("ktbt lsp: checking %s failed; no diagnostics", uri)
                return
            current = self.documents.get(uri)
            if current is None:
                return
            if current.version != version:
                continue  # the text changed meanwhile: check the newest instead
            self.publish(current, checked, reason)
            return

    @guarded
    def publish(self, document: Document, checked: Checked, reason: str | None) -> None:
        diagnostics = [_diagnostic(document, p) for p in checked.problems]
        if reason is not None:
            end = document.position_at(len(document.line_text(0)))
            diagnostics.insert(
                0,
                lsp.Diagnostic(
                    range=lsp.Range(start=lsp.Position(0, 0), end=end),
                    message=f"{reason} (checked without a vocabulary)",
                    severity=lsp.DiagnosticSeverity.Error,
                    code=CONFIGURATION,
                    source=SOURCE,
                ),
            )
        self.text_document_publish_diagnostics(
            lsp.PublishDiagnosticsParams(
                uri=document.uri, diagnostics=diagnostics, version=document.version
            )
        )


def _diagnostic(document: Document, problem: Problem) -> lsp.Diagnostic:
    return lsp.Diagnostic(
        range=document.range_of(problem.start, problem.end),
        message=problem.error.message,
        severity=lsp.DiagnosticSeverity.Warning
        if problem.warning
        else lsp.DiagnosticSeverity.Error,
        code=problem.error.code.value,
        source=SOURCE,
    )


def _edits(document: Document, edits: list[Edit]) -> list[lsp.TextEdit]:
    return [lsp.TextEdit(range=document.range_of(e.start, e.end), new_text=e.new) for e in edits]


_COMPLETION_KIND = {
    "tag": lsp.CompletionItemKind.Keyword,
    "close": lsp.CompletionItemKind.Keyword,
    "condition": lsp.CompletionItemKind.Interface,
    "action": lsp.CompletionItemKind.Function,
    "argument": lsp.CompletionItemKind.Field,
    "value": lsp.CompletionItemKind.Value,
    "placeholder": lsp.CompletionItemKind.Module,
}


def build(vocabulary: str | None = None, debounce: float = DEBOUNCE) -> KtbtServer:
    """The server with every feature registered."""
    server = KtbtServer(vocabulary, debounce)

    @server.feature(lsp.TEXT_DOCUMENT_DID_OPEN)
    @guarded
    def did_open(ls: KtbtServer, params: lsp.DidOpenTextDocumentParams) -> None:
        item = params.text_document
        ls.documents[item.uri] = Document(item.uri, item.text, item.version, ls.encoding)
        ls.schedule(item.uri, 0)

    @server.feature(lsp.TEXT_DOCUMENT_DID_CHANGE)
    @guarded
    def did_change(ls: KtbtServer, params: lsp.DidChangeTextDocumentParams) -> None:
        uri = params.text_document.uri
        document = ls.documents.get(uri)
        if document is None:
            return
        document.apply(params.content_changes, params.text_document.version)
        ls.schedule(uri, ls.debounce)

    @server.feature(lsp.TEXT_DOCUMENT_DID_SAVE)
    @guarded
    def did_save(ls: KtbtServer, params: lsp.DidSaveTextDocumentParams) -> None:
        if params.text_document.uri in ls.documents:
            ls.schedule(params.text_document.uri, 0)

    @server.feature(lsp.TEXT_DOCUMENT_DID_CLOSE)
    @guarded
    def did_close(ls: KtbtServer, params: lsp.DidCloseTextDocumentParams) -> None:
        uri = params.text_document.uri
        ls.documents.pop(uri, None)
        ls._outlines.pop(uri, None)
        ls.text_document_publish_diagnostics(lsp.PublishDiagnosticsParams(uri=uri, diagnostics=[]))

    @server.feature(lsp.TEXT_DOCUMENT_FORMATTING)
    @guarded
    def formatting(
        ls: KtbtServer, params: lsp.DocumentFormattingParams
    ) -> list[lsp.TextEdit] | None:
        document = ls.document(params.text_document.uri)
        if document is None:
            return None
        return _edits(document, format_edits(document.text))

    @server.feature(lsp.TEXT_DOCUMENT_RANGE_FORMATTING)
    @guarded
    def range_formatting(
        ls: KtbtServer, params: lsp.DocumentRangeFormattingParams
    ) -> list[lsp.TextEdit] | None:
        document = ls.document(params.text_document.uri)
        if document is None:
            return None
        first = document.sbt_position(document.offset_at(params.range.start))[0] - 1
        last = document.sbt_position(document.offset_at(params.range.end))[0] - 1
        return _edits(document, format_edits(document.text, (first, last)))

    @server.feature(
        lsp.TEXT_DOCUMENT_COMPLETION,
        lsp.CompletionOptions(trigger_characters=["<", "(", ",", "=", "!"]),
    )
    @guarded
    def completion(ls: KtbtServer, params: lsp.CompletionParams) -> lsp.CompletionList | None:
        document = ls.document(params.text_document.uri)
        if document is None:
            return None
        offset = document.offset_at(params.position)
        known, _ = ls.known(document.uri)
        items = assist.complete(document.text, ls.outline(document), offset, known)
        return lsp.CompletionList(
            is_incomplete=False,
            items=[
                lsp.CompletionItem(
                    label=item.label,
                    kind=_COMPLETION_KIND[item.kind],
                    detail=item.detail or None,
                    documentation=lsp.MarkupContent(kind=lsp.MarkupKind.Markdown, value=item.doc)
                    if item.doc
                    else None,
                    sort_text=item.order,
                    preselect=item.kind == "close" or None,
                    filter_text=item.label,
                    text_edit=lsp.TextEdit(
                        range=document.range_of(item.start, item.end), new_text=item.insert
                    ),
                )
                for item in items
            ],
        )

    @server.feature(lsp.TEXT_DOCUMENT_HOVER)
    @guarded
    def hover(ls: KtbtServer, params: lsp.HoverParams) -> lsp.Hover | None:
        document = ls.document(params.text_document.uri)
        if document is None:
            return None
        known, _ = ls.known(document.uri)
        offset = document.offset_at(params.position)
        found = assist.hover(document.text, ls.outline(document), offset, known)
        if found is None:
            return None
        return lsp.Hover(
            contents=lsp.MarkupContent(kind=lsp.MarkupKind.Markdown, value=found.markdown),
            range=document.range_of(found.start, found.end),
        )

    @server.feature(lsp.TEXT_DOCUMENT_DOCUMENT_SYMBOL)
    @guarded
    def document_symbol(
        ls: KtbtServer, params: lsp.DocumentSymbolParams
    ) -> list[lsp.DocumentSymbol] | None:
        document = ls.document(params.text_document.uri)
        if document is None:
            return None
        return navigation.symbols(document, ls.outline(document))

    @server.feature(lsp.TEXT_DOCUMENT_FOLDING_RANGE)
    @guarded
    def folding_range(
        ls: KtbtServer, params: lsp.FoldingRangeParams
    ) -> list[lsp.FoldingRange] | None:
        document = ls.document(params.text_document.uri)
        if document is None:
            return None
        return navigation.folding_ranges(document, ls.outline(document))

    @server.feature(lsp.TEXT_DOCUMENT_DEFINITION)
    @guarded
    def definition(ls: KtbtServer, params: lsp.DefinitionParams) -> lsp.Location | None:
        document = ls.document(params.text_document.uri)
        if document is None:
            return None
        known, _ = ls.known(document.uri)
        offset = document.offset_at(params.position)
        found = navigation.definition(ls.outline(document), offset, known)
        if found is None:
            return None
        path, line = found
        start = lsp.Position(line=line, character=0)
        return lsp.Location(
            uri=from_fs_path(str(path)) or path.as_uri(), range=lsp.Range(start=start, end=start)
        )

    @server.feature(
        lsp.TEXT_DOCUMENT_CODE_ACTION,
        lsp.CodeActionOptions(code_action_kinds=[lsp.CodeActionKind.QuickFix]),
    )
    @guarded
    def code_action(ls: KtbtServer, params: lsp.CodeActionParams) -> list[lsp.CodeAction] | None:
        document = ls.document(params.text_document.uri)
        if document is None:
            return None
        known, _ = ls.known(document.uri)
        checked = check(document.text, known.registry if known is not None else None)
        first = document.offset_at(params.range.start)
        last = document.offset_at(params.range.end)
        actions = []
        for problem in checked.problems:
            if problem.end < first or problem.start > last:
                continue
            if problem.error.code is ErrorCode.ACTIONS_RERUN:
                fix = memory_form(document.text, problem.error, ls.outline(document))
            elif problem.error.code is ErrorCode.UNEXPECTED_END:
                fix = close_open_nodes(document.text, ls.outline(document))
            else:
                continue
            if fix is None:
                continue
            actions.append(
                lsp.CodeAction(
                    title=fix.title,
                    kind=lsp.CodeActionKind.QuickFix,
                    diagnostics=[_diagnostic(document, problem)],
                    is_preferred=True,
                    edit=lsp.WorkspaceEdit(changes={document.uri: _edits(document, fix.edits)}),
                )
            )
        return actions

    @server.feature(
        lsp.TEXT_DOCUMENT_SEMANTIC_TOKENS_FULL,
        lsp.SemanticTokensRegistrationOptions(legend=navigation.LEGEND, full=True, range=True),
    )
    @guarded
    def semantic_tokens(
        ls: KtbtServer, params: lsp.SemanticTokensParams
    ) -> lsp.SemanticTokens | None:
        document = ls.document(params.text_document.uri)
        if document is None:
            return None
        data = navigation.semantic_tokens(document, ls.outline(document))
        return None if data is None else lsp.SemanticTokens(data=data)

    @server.feature(lsp.TEXT_DOCUMENT_SEMANTIC_TOKENS_RANGE)
    @guarded
    def semantic_tokens_range(
        ls: KtbtServer, params: lsp.SemanticTokensRangeParams
    ) -> lsp.SemanticTokens | None:
        document = ls.document(params.text_document.uri)
        if document is None:
            return None
        start, end = document.offset_at(params.range.start), document.offset_at(params.range.end)
        data = navigation.semantic_tokens(document, ls.outline(document), start, end)
        return None if data is None else lsp.SemanticTokens(data=data)

    return server
