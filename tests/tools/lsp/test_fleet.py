"""``ktbt lsp --fleet``: a real ``ktbt peer serve`` teacher of the colour skills, and the server
started over stdio with ``--fleet`` on the teacher's endpoint. An item the teacher knows with
another subtree gets a ``ktbt fleet`` warning and a hover naming the teacher; an item it teaches
the same gets none; without ``--fleet`` no zenoh is ever loaded. Every wait is for something the
server sends, bounded by a deadline."""

from __future__ import annotations

import asyncio
import subprocess
import sys
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import Any

import pytest
import pytest_asyncio
from lsprotocol import types as lsp
from pytest_lsp import LanguageClient, client_capabilities
from pytest_lsp.client import make_test_lsp_client

from tests.zenoh_helpers import endpoint, free_port, serving

pytestmark = [pytest.mark.asyncio(loop_scope="module"), pytest.mark.network]
WAIT = 30.0
"""Seconds a test waits for the fleet at most (a catalog round is every few seconds)."""

GREEN_OTHER = """<k>(prior)
    <sq>
        <c>(TargetSeen, colour=2)
        <a>(PickTreasure)
        <a>(AssignCollectionPoint, colour=3)
    <e>
<e>
"""
GREEN_SAME = GREEN_OTHER.replace("colour=3)", "colour=2)")


class Client:
    """A server started with ``args``, and every diagnostic it published, by document."""

    def __init__(self) -> None:
        self.lsp: LanguageClient = make_test_lsp_client()
        self.published: dict[str, list[lsp.Diagnostic]] = {}
        features = self.lsp.protocol.fm.features
        original = features[lsp.TEXT_DOCUMENT_PUBLISH_DIAGNOSTICS]

        def publish(params: lsp.PublishDiagnosticsParams) -> None:
            self.published[params.uri] = list(params.diagnostics)
            original(params)

        features[lsp.TEXT_DOCUMENT_PUBLISH_DIAGNOSTICS] = publish

    async def start(self, *args: str, root: Path) -> None:
        await self.lsp.start_io(sys.executable, "-m", "ktbt_proto", "lsp", *args)
        await self.lsp.initialize_session(
            lsp.InitializeParams(
                capabilities=client_capabilities("visual-studio-code"), root_uri=root.as_uri()
            )
        )

    async def stop(self) -> None:
        await self.lsp.shutdown_session()
        await self.lsp.stop()  # type: ignore[no-untyped-call]

    def open(self, path: Path, text: str) -> str:
        uri = path.as_uri()
        self.lsp.text_document_did_open(
            lsp.DidOpenTextDocumentParams(
                text_document=lsp.TextDocumentItem(
                    uri=uri, language_id="stringbt", version=1, text=text
                )
            )
        )
        return uri

    def fleet(self, uri: str) -> list[lsp.Diagnostic]:
        return [d for d in self.published.get(uri, []) if d.source == "ktbt fleet"]

    async def until(self, done: Any, seconds: float = WAIT) -> bool:
        deadline = asyncio.get_running_loop().time() + seconds
        while not done():
            if asyncio.get_running_loop().time() > deadline:
                return False
            await asyncio.sleep(0.05)
        return True

    async def hover(self, uri: str, line: int, character: int) -> str:
        found = await self.lsp.text_document_hover_async(
            lsp.HoverParams(
                text_document=lsp.TextDocumentIdentifier(uri=uri),
                position=lsp.Position(line=line, character=character),
            )
        )
        if found is None:
            return ""
        assert isinstance(found.contents, lsp.MarkupContent)
        return found.contents.value


@pytest.fixture(scope="module")
def teacher() -> Iterator[str]:
    port = free_port()
    with serving(port):
        yield endpoint(port)


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def fleet_client(
    teacher: str, tmp_path_factory: pytest.TempPathFactory
) -> AsyncIterator[tuple[Client, Path]]:
    root = tmp_path_factory.mktemp("fleet")
    client = Client()
    await client.start("--fleet", teacher, root=root)
    try:
        yield client, root
    finally:
        await client.stop()


async def test_an_item_the_fleet_teaches_otherwise_is_warned_and_its_knowers_shown(
    fleet_client: tuple[Client, Path],
) -> None:
    client, root = fleet_client
    uri = client.open(root / "other.sbt", GREEN_OTHER)
    assert await client.until(lambda: client.fleet(uri)), client.published.get(uri)
    (warning,) = client.fleet(uri)
    assert warning.severity == lsp.DiagnosticSeverity.Warning
    assert warning.code is None
    assert "teacher" in warning.message
    assert "<a>(AssignCollectionPoint,colour=2)" in warning.message
    assert warning.range.start.line == 1
    said = await client.hover(uri, 2, 12)  # on TargetSeen, inside the item
    assert "Known in the fleet by: teacher" in said
    assert "TargetSeen" in said  # the vocabulary's hover is kept


async def test_an_item_the_fleet_agrees_with_gets_nothing(
    fleet_client: tuple[Client, Path],
) -> None:
    client, root = fleet_client
    other = client.open(root / "other2.sbt", GREEN_OTHER)
    same = client.open(root / "same.sbt", GREEN_SAME)
    # Once the fleet has spoken of the other file, it has of this one too (same sequence).
    assert await client.until(lambda: client.fleet(other))
    assert await client.until(lambda: same in client.published)
    assert client.fleet(same) == []
    assert "Known in the fleet by: teacher" in await client.hover(same, 1, 5)


async def test_without_fleet_no_network(tmp_path: Path) -> None:
    client = Client()
    await client.start(root=tmp_path)
    try:
        uri = client.open(tmp_path / "other.sbt", GREEN_OTHER)
        assert await client.until(lambda: uri in client.published)
        assert client.fleet(uri) == []
        assert "Known in the fleet" not in await client.hover(uri, 1, 5)
    finally:
        await client.stop()


async def test_without_fleet_zenoh_is_never_loaded() -> None:
    """The server built as ``ktbt lsp`` builds it, and initialized, imports no zenoh."""
    script = (
        "import asyncio, sys\n"
        "from ktbt_proto.tools.lsp.server import build\n"
        "server = build()\n"
        "async def main():\n"
        "    server.start_fleet()\n"
        "asyncio.run(main())\n"
        "assert server.fleet is None\n"
        "assert 'zenoh' not in sys.modules, 'zenoh loaded'\n"
    )
    done = await asyncio.to_thread(
        subprocess.run, [sys.executable, "-c", script], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stderr


async def test_items_and_knowers_are_read_without_a_network() -> None:
    from ktbt_proto.tools.lsp.fleet import Snapshot, item_of

    found = item_of("<sq><c>(TargetSeen,colour=2)<a>(PickTreasure)<e>")
    assert found is not None
    key, subtree = found
    assert subtree == "<a>(PickTreasure)"
    assert item_of("<a>(PickTreasure)") is None
    assert item_of("<sq><c>(A)") is None  # not stringBT: no item, no exception
    snapshot = Snapshot({"b": [{"sequence": key, "author": "K"}], "a": [{"sequence": "x"}]})
    assert snapshot.knowers(key) == [("b", "K")]
    assert snapshot.knowers("nothing") == []
