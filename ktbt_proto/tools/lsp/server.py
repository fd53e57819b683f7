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
  and the last one answers the text as it is. Each check starts from the one before it: an
  edit inside a leaf's parentheses reads that leaf again and validates it alone instead of
  reading the whole text again (:mod:`.diagnostics`, with the same result).
- **One vocabulary per document, loaded once** (:class:`.vocabulary.Vocabularies`).

With ``--fleet ENDPOINT`` (off by default), :mod:`.fleet` reads the fleet's catalogs in a
thread of its own; hover on an item says which robots know its sequence, and an item that
differs from what the fleet teaches for that sequence gets a warning of source ``ktbt fleet``.
Handlers only read the fleet's latest snapshot: none waits on the network.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import wraps
from pathlib import Path
from typing import TYPE_CHECKING, ParamSpec, TypeVar

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
from ktbt_proto.tools.lsp.vocabularies import Known, Vocabularies

if TYPE_CHECKING:
    from ktbt_proto.tools.lsp.fleet import Fleet

log = logging.getLogger("ktbt.lsp")

SOURCE = "ktbt"
FLEET_SOURCE = "ktbt fleet"
"""The source of what the fleet says (no SBT code: the fleet's word, not the language's)."""
DEBOUNCE = 0.0
"""Seconds a check waits after a change for more to come: none by default, since changes that
come while a check runs are folded into the next one anyway (``ktbt lsp`` answers a keystroke
inside a leaf in two fifths of a ``ktbt check``, any other in 1.2: benchmarks/README.md)."""
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

    def __init__(
        self, vocabulary: str | None = None, debounce: float = DEBOUNCE, fleet: str | None = None
    ) -> None:
        super().__init__(
            "ktbt", __version__, text_document_sync_kind=lsp.TextDocumentSyncKind.Incremental
        )
        self.documents: dict[str, Document] = {}
        self.vocabularies = Vocabularies(vocabulary)
        self.debounce = debounce
        self._checks: dict[str, asyncio.Task[None]] = {}
        self._checked: dict[str, tuple[Document, Checked]] = {}
        self._paths: dict[str, Path | None] = {}
        self._outlines: dict[str, tuple[int, Outline]] = {}
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="ktbt-check")
        self.fleet_endpoint = fleet
        self.fleet: Fleet | None = None
        self._items: dict[str, tuple[int, list[FleetItem]]] = {}

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
        if uri not in self._paths:  # a document's path, read from its URI once
            path = to_fs_path(uri)
            self._paths[uri] = Path(path) if path else None
        return self.vocabularies.for_path(self._paths[uri])

    # -- the fleet (off without --fleet) ------------------------------------------------------

    def start_fleet(self) -> None:
        """Open the fleet's reader, once the event loop runs (it re-publishes through it)."""
        if self.fleet_endpoint is None or self.fleet is not None:
            return
        from ktbt_proto.tools.lsp.fleet import Fleet

        loop = asyncio.get_running_loop()

        def changed() -> None:
            loop.call_soon_threadsafe(self.refleet)

        self.fleet = Fleet(self.fleet_endpoint, changed)
        self.fleet.start()

    def refleet(self) -> None:
        """What the fleet says changed: check every open document again."""
        for uri in list(self.documents):
            self.schedule(uri, 0)

    def fleet_items(self, document: Document) -> list[FleetItem]:
        cached = self._items.get(document.uri)
        if cached is not None and cached[0] == document.version:
            return cached[1]
        from ktbt_proto.tools.lsp.fleet import item_of

        items = []
        for node, _ in self.outline(document).walk():
            if node.tag != "<k>":
                continue
            for child in node.children:
                if not child.closed:
                    continue
                found = item_of(document.text[child.start : child.end])
                if found is not None:
                    items.append(
                        FleetItem(found[0], found[1], child.start, child.head_end, child.end)
                    )
        self._items[document.uri] = (document.version, items)
        if self.fleet is not None:
            self.fleet.want(
                i.key for uri in self.documents for i in self._items.get(uri, (0, []))[1]
            )
        return items

    def fleet_diagnostics(self, document: Document) -> list[lsp.Diagnostic]:
        if self.fleet is None:
            return []
        snapshot = self.fleet.snapshot()
        out = []
        for item in self.fleet_items(document):
            taught = snapshot.answers.get(item.key, {})
            differ = sorted(peer for peer, form in taught.items() if form != item.subtree)
            if not differ:
                continue
            peer = differ[0]
            out.append(
                lsp.Diagnostic(
                    range=document.range_of(item.start, item.head_end),
                    message=f"the fleet teaches another subtree for this sequence: {peer} "
                    f"teaches {_clip(taught[peer])}"
                    + (f" (and {len(differ) - 1} more)" if len(differ) > 1 else ""),
                    severity=lsp.DiagnosticSeverity.Warning,
                    source=FLEET_SOURCE,
                )
            )
        return out

    def fleet_hover(self, document: Document, offset: int) -> tuple[str, int, int] | None:
        """Which robots know the sequence of the item at ``offset``, from their catalogs."""
        if self.fleet is None:
            return None
        item = next((i for i in self.fleet_items(document) if i.start <= offset < i.end), None)
        if item is None:
            return None
        knowers = self.fleet.snapshot().knowers(item.key)
        if not knowers:
            return "Known in the fleet by: nobody", item.start, item.head_end
        said = ", ".join(
            f"{peer} (author {author})" if author else peer for peer, author in knowers
        )
        return f"Known in the fleet by: {said}", item.start, item.head_end

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
            version, text, same = document.version, document.text, document.take_edits()
            last = self._checked.pop(uri, None)
            previous = last[1] if last is not None and last[0] is document else None
            try:
                known, reason = self.known(uri)
                registry = known.registry if known is not None else None
                checked = await loop.run_in_executor(
                    self._worker, check, text, registry, previous, same
                )
            except Exception:
                log.exception("ktbt lsp: checking %s failed; no diagnostics", uri)
                return
            current = self.documents.get(uri)
            if current is not document:
                return  # closed (or closed and opened again) meanwhile
            self._checked[uri] = (document, checked)
            if current.version != version:
                continue  # the text changed meanwhile: check the newest instead
            self.publish(current, checked, reason)
            return

    @guarded
    def publish(self, document: Document, checked: Checked, reason: str | None) -> None:
        diagnostics = [_diagnostic(document, p) for p in checked.problems]
        diagnostics += self.fleet_diagnostics(document)
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


@dataclass(frozen=True)
class FleetItem:
    """An item of a document's placeholder: its sequence key, its subtree (canonical compact),
    and where it is written (its ``<sq>``'s head, and its end)."""

    key: str
    subtree: str
    start: int
    head_end: int
    end: int


def _clip(text: str, most: int = 200) -> str:
    """A peer's text as a message shows it: at most ``most`` characters."""
    return text if len(text) <= most else text[: most - 1] + "…"


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


def build(
    vocabulary: str | None = None, debounce: float = DEBOUNCE, fleet: str | None = None
) -> KtbtServer:
    """The server with every feature registered; with ``fleet``, an endpoint, the fleet's
    view too (:mod:`.fleet`)."""
    server = KtbtServer(vocabulary, debounce, fleet)

    @server.feature(lsp.INITIALIZED)
    @guarded
    def initialized(ls: KtbtServer, params: lsp.InitializedParams) -> None:
        ls.start_fleet()

    @server.feature(lsp.SHUTDOWN)
    @guarded
    def shutdown(ls: KtbtServer, params: None) -> None:
        if ls.fleet is not None:
            ls.fleet.stop()

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
        ls._checked.pop(uri, None)
        ls._paths.pop(uri, None)
        ls._outlines.pop(uri, None)
        ls._items.pop(uri, None)
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
        fleet = ls.fleet_hover(document, offset)
        if found is None:
            if fleet is None:
                return None
            markdown, start, end = fleet
        else:
            markdown, start, end = found.markdown, found.start, found.end
            if fleet is not None:
                markdown = f"{markdown}\n\n{fleet[0]}"
        return lsp.Hover(
            contents=lsp.MarkupContent(kind=lsp.MarkupKind.Markdown, value=markdown),
            range=document.range_of(start, end),
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
        latest = ls._checked.get(document.uri)  # the latest check, when it is of this text
        previous = latest[1] if latest is not None and latest[0] is document else None
        everything = (len(document.text), len(document.text))
        checked = check(
            document.text, known.registry if known is not None else None, previous, everything
        )
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
