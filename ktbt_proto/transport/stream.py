"""The fleet events, catalogs and control trees of agents in this process (a simulator's, on
the in-memory network), put on one zenoh session for ``ktbt monitor`` (``spec/protocol.md``
sections 3 and 10), as a peer with ``--publish-events`` puts its own."""

from __future__ import annotations

import json
import threading
from collections.abc import Callable, Iterable
from dataclasses import replace
from typing import Any

from ktbt_proto.exchange.answers import catalog
from ktbt_proto.exchange.core import AgentCore
from ktbt_proto.exchange.events import DEFAULT_RATE, EventPublisher
from ktbt_proto.exchange.messages import MAX_MESSAGE_BYTES
from ktbt_proto.exchange.transferlog import TransferLog
from ktbt_proto.formatter import format_tree
from ktbt_proto.transport.zenoh import PREFIX, open_session, reply_catalog, reply_tree


class AgentStream:
    """The fleet events of agents in this process, published on one zenoh session described by
    ``settings``, each on its agent's own key (section 10). Each agent gets a transfer log if
    it has none (no file: sinks only). Each agent's catalog (``ktbt/v1/catalog/<name>``,
    section 3) and control tree (``ktbt/v1/tree/<name>``, section 10) are served too, so a
    monitor shows what the agents knew before they learned anything, and their trees. The
    agents declare no knowledge queryable and no liveliness token, since nobody answers
    queries for them on the network; a monitor shows them as heard. Close to stop.

    The agents run in the caller's thread, the queryables in zenoh's: a catalog is taken in
    the recording thread whenever an agent merges or forgets (the log's events say so) and
    served from that copy; a control tree is never changed in place, only replaced, so it is
    read as it is."""

    def __init__(
        self, agents: Iterable[AgentCore], settings: Any, rate: float = DEFAULT_RATE
    ) -> None:
        try:
            self._session = open_session(settings)
        except Exception as exc:  # zenoh's own error: a bad endpoint, a port in use
            raise ValueError(f"cannot publish events: {exc}") from None
        self._declared: list[Any] = []
        self._zenoh_publishers: list[Any] = []
        self.publishers: list[EventPublisher] = []
        self._logs: list[tuple[TransferLog, Callable[[dict[str, Any]], None]]] = []
        self._catalogs: dict[str, bytes] = {}
        self._read: set[str] = set()
        """Agents whose catalog was read while their events had a subscriber."""
        self._watched = threading.Condition()
        self._all_read = False
        """Every catalog was read so: queries no longer look at the publishers."""
        try:
            for agent in agents:
                self._stream(agent, catalog(agent.knowledge), rate)
        except BaseException:
            self.close()
            raise

    def _stream(self, agent: AgentCore, entries: Callable[[], list[Any]], rate: float) -> None:
        name = agent.name
        publisher, declared = EventPublisher.on_session(self._session, name, rate=rate)
        self._declared.append(declared)
        self._zenoh_publishers.append(declared)
        self.publishers.append(publisher)
        self._catalogs[name] = json.dumps(entries()).encode()

        def changed(entry: dict[str, Any]) -> None:
            if entry.get("event") in ("merged", "forgotten"):
                self._catalogs[name] = json.dumps(entries()).encode()

        def on_catalog(query: Any) -> None:
            reply_catalog(query, name, self._catalogs[name])
            if not self._all_read and name not in self._read:
                self._seen(name)

        def on_tree(query: Any) -> None:
            reply_tree(query, name, format_tree(agent.control.tree, "compact"), MAX_MESSAGE_BYTES)

        self._declared.append(
            self._session.declare_queryable(f"{PREFIX}/catalog/{name}", on_catalog)
        )
        self._declared.append(self._session.declare_queryable(f"{PREFIX}/tree/{name}", on_tree))
        log = agent.security.log or TransferLog(None)
        agent.security = replace(agent.security, log=log)
        for sink in (publisher, changed):
            log.add_sink(sink)
            self._logs.append((log, sink))

    def _seen(self, name: str) -> None:
        """``name``'s catalog was read: it counts if every agent's events have a subscriber."""
        if all(p.matching_status.matching for p in self._zenoh_publishers):
            with self._watched:
                self._read.add(name)
                self._all_read = len(self._read) == len(self._catalogs)
                self._watched.notify_all()

    def wait_watched(self, timeout: float) -> bool:
        """Wait until a monitor watches: every agent's events have a subscriber and its catalog
        was read since, so the monitor knows what the agents start with and hears what follows.
        False if that did not happen within ``timeout`` seconds (``inf``, or any longer than a
        thread can wait, ``threading.TIMEOUT_MAX``: wait for ever)."""
        with self._watched:
            return self._watched.wait_for(
                lambda: len(self._read) == len(self._catalogs),
                timeout=timeout if timeout < threading.TIMEOUT_MAX else None,
            )

    def close(self) -> None:
        for log, sink in self._logs:
            log.remove_sink(sink)
        self._logs = []
        for declared in self._declared:
            declared.undeclare()
        self._declared = []
        self._session.close()  # type: ignore[no-untyped-call]

    def __enter__(self) -> AgentStream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
