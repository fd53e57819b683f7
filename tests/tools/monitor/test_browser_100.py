"""`ktbt monitor` with a fleet of 100 peers, in a real headless Chromium at 1280x800 and
1920x1080: the document never scrolls sideways (the matrix scrolls in its own box), every peer is
listed with what it learned, and the spreading chart has its axis titles and a legend outside
its plot (spec section 10).

The 100 peers are real zenoh publishers, not `ktbt peer` processes (a hundred of those cost
about 5 GB here): four sessions, as four groups of a fleet would be, each holding 25 peers' own
liveliness tokens and event publishers, and publishing, paced in real time, each peer's merge of
each of four items as a peer does (``ktbt/v1/events/<id>``). The monitor and the page are the
real ones. Set ``KTBT_MONITOR_SCREENSHOT=docs/images/monitor-100.png`` to keep the 1920x1080
picture of the page for the docs."""

from __future__ import annotations

import os
import random
import time
import urllib.request
from collections.abc import Iterator
from contextlib import ExitStack
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest

from ktbt_proto.exchange.events import FleetEvent, encode_event
from ktbt_proto.items import sequence_digest
from tests.browser import chromium, unavailable
from tests.zenoh_helpers import endpoint, free_port, ktbt_process, wait_until

SKIP = unavailable()
pytestmark = pytest.mark.skipif(SKIP is not None, reason=f"no browser: {SKIP}")

PEERS = [f"r{k:03d}" for k in range(100)]
ITEMS = [
    "<c>(TargetSeen,colour=2)",
    "<c>(TargetSeen,colour=3)",
    "<c>(Carrying)",
    "<c>(AtCollectionPoint)",
]
SIZES = [(1280, 800), (1920, 1080)]


def _up(url: str) -> bool:
    try:
        with urllib.request.urlopen(url, timeout=1) as reply:
            return bool(reply.status == 200)
    except OSError:
        return False


def _plan() -> list[tuple[float, str, int, str]]:
    """When (s from the start) each peer merges each item, and from whom: each item starts at
    its own time and spreads through the fleet in its own order, faster as more peers know it."""
    plan = []
    for k, _ in enumerate(ITEMS):
        order = PEERS[:]
        random.Random(k).shuffle(order)
        at = 0.5 * k
        for j, name in enumerate(order):
            at += 0.04 / (1 + j / 10)
            plan.append((at, name, k, order[j - 1] if j else "teacher"))
    return sorted(plan)


@pytest.fixture
def hundred() -> Iterator[tuple[str, list[Any]]]:
    """A hub listening on loopback, four sessions of 25 peers each connected to it, each peer
    with its liveliness token and its events publisher, and the monitor on the hub."""
    from ktbt_proto.transport.zenoh import ZenohSettings, open_session

    port, http = free_port(), free_port()
    with ExitStack() as stack:
        sessions = []
        hub = open_session(ZenohSettings(listen=[endpoint(port)]))
        stack.callback(hub.close)
        for _ in range(4):
            session = open_session(ZenohSettings(connect=[endpoint(port)]))
            stack.callback(session.close)
            sessions.append(session)
        publishers = []
        for k, name in enumerate(PEERS):
            session = sessions[k % len(sessions)]
            token = session.liveliness().declare_token(f"ktbt/v1/peers/{name}")
            stack.callback(token.undeclare)
            publisher = session.declare_publisher(f"ktbt/v1/events/{name}")
            stack.callback(publisher.undeclare)
            publishers.append(publisher)
        stack.enter_context(
            ktbt_process(
                "monitor", "--connect", endpoint(port), "--http", f"127.0.0.1:{http}",
                ready="localhost only",
            )
        )  # fmt: skip
        url = f"http://127.0.0.1:{http}/"
        assert wait_until(lambda: _up(url), 15)
        yield url, publishers


CONTROL = "return document.getElementById('detail-control').textContent"
LAYOUT = """
const rect = (e) => { const r = e.getBoundingClientRect();
  return {left: r.left, top: r.top, right: r.right, bottom: r.bottom}; };
const q = (s) => document.querySelector(s);
return {
  inner: window.innerWidth,
  scroll: document.documentElement.scrollWidth,
  plot: rect(q('#timeline')),
  legend: rect(q('#timeline-legend')),
  x: rect(q('#timeline-x')), y: rect(q('#timeline-y')),
  xText: q('#timeline-x').textContent, yText: q('#timeline-y').textContent,
  lines: q('#timeline-legend').children.length,
  matrix: rect(q('#matrix-section .scroll')),
};
"""


def _apart(a: dict[str, float], b: dict[str, float]) -> bool:
    return (
        a["right"] <= b["left"]
        or b["right"] <= a["left"]
        or a["bottom"] <= b["top"]
        or b["bottom"] <= a["top"]
    )


def test_a_hundred_peers_fit_the_page_at_1280_and_1920(
    hundred: tuple[str, list[Any]], tmp_path: Path
) -> None:
    url, publishers = hundred
    with chromium(*SIZES[0]) as driver:
        driver.get(url)

        def js(script: str) -> Any:
            return driver.execute_script(script)

        present = "return document.querySelectorAll('#matrix tbody tr[data-status=present]').length"
        assert wait_until(lambda: js(present) == len(PEERS), 30), js(present)

        start = time.monotonic()
        sent = dict.fromkeys(PEERS, 0)
        for at, name, k, teacher in _plan():  # paced: each event carries the time it is sent
            time.sleep(max(0.0, at - (time.monotonic() - start)))
            now = datetime.now(UTC).isoformat(timespec="milliseconds")
            event = FleetEvent(
                peer=name, n=sent[name], t=now, event="merged",
                item=sequence_digest(ITEMS[k]), sequence=ITEMS[k], teacher=teacher,
            )  # fmt: skip
            publishers[PEERS.index(name)].put(encode_event(event))
            sent[name] += 1

        learned = "return document.querySelectorAll('#matrix td[data-how=learned]').length"
        assert wait_until(lambda: js(learned) == len(PEERS) * len(ITEMS), 30), js(learned)
        listed = js(
            "return [...document.querySelectorAll('#matrix tbody tr')]"
            ".map(tr => tr.getAttribute('data-peer'))"
        )
        assert sorted(listed) == PEERS
        # A peer clicked, as one is when looked at: its detail (here, that it has no tree to
        # give: these peers answer no tree asks) must fit its column too.
        js("document.querySelector('#matrix tbody tr[data-peer=r042] th').click();")
        assert wait_until(lambda: "no tree from r042" in js(CONTROL), 15), js(CONTROL)

        for width, height in SIZES:
            driver.set_window_size(width, height)  # the window's: the viewport made the size
            inner = js("return [window.innerWidth, window.innerHeight]")
            driver.set_window_size(2 * width - inner[0], 2 * height - inner[1])
            viewport = "return [innerWidth, innerHeight]"
            assert wait_until(lambda: js(viewport) == [width, height], 10), js(viewport)  # noqa: B023
            assert wait_until(lambda: js(LAYOUT)["lines"] == len(ITEMS), 10)
            layout = js(LAYOUT)
            assert layout["scroll"] <= layout["inner"], (width, layout)  # no sideways scroll
            assert layout["plot"]["right"] <= layout["inner"], (width, layout)
            assert layout["matrix"]["right"] <= layout["inner"], (width, layout)
            assert layout["yText"] == "peers knowing", layout
            assert layout["xText"].startswith("time"), layout
            for other in ("legend", "x", "y"):  # the titles and the legend beside the plot
                assert _apart(layout[other], layout["plot"]), (width, other, layout)
            driver.save_screenshot(str(tmp_path / f"monitor-{width}.png"))
        keep = os.environ.get("KTBT_MONITOR_SCREENSHOT")
        if keep:
            Path(keep).write_bytes((tmp_path / f"monitor-{SIZES[-1][0]}.png").read_bytes())
