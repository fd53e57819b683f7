"""`ktbt monitor` in a real headless Chromium over a fleet of real `ktbt peer` processes on
loopback: peers appear, a learned item shows in the matrix within 1 s of its merge, a refused
answer shows with its reason, a killed peer is marked gone; and hostile names, items and
reasons never run or render as markup, while junk, oversized and flooding streams are dropped
and counted on the page."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import urllib.error
import urllib.request
from collections.abc import Iterator
from contextlib import ExitStack
from datetime import datetime
from pathlib import Path
from typing import Any

import pytest

from ktbt_proto.exchange.events import FleetEvent, encode_event, signed_bytes
from ktbt_proto.exchange.signing import Identity
from ktbt_proto.items import sequence_digest
from tests.browser import chromium, unavailable
from tests.fleet_helpers import sweep
from tests.zenoh_helpers import ROOT, endpoint, free_port, ktbt_process, serving, wait_until

SKIP = unavailable()
pytestmark = pytest.mark.skipif(SKIP is not None, reason=f"no browser: {SKIP}")

GREEN = "<c>(TargetSeen,colour=2)"
CARRYING = "<c>(Carrying)"
BAD = "<k>(new)\n<sq><c>(Carrying)<a>(AssignCollectionPoint, colour=7)<e>\n<e>\n"


def _ms(t: str) -> int:
    return int(datetime.fromisoformat(t).timestamp() * 1000)


def _up(url: str) -> bool:
    try:
        with urllib.request.urlopen(url, timeout=1) as reply:
            return bool(reply.status == 200)
    except OSError:
        return False


class Page:
    """The monitor's page in the browser, read through its DOM only."""

    def __init__(self, driver: Any) -> None:
        self.driver = driver

    def js(self, script: str, *args: Any) -> Any:
        return self.driver.execute_script(script, *args)

    def status(self, peer: str) -> str | None:
        found: str | None = self.js(
            "for (const tr of document.querySelectorAll('#matrix tbody tr'))"
            "  if (tr.getAttribute('data-peer') === arguments[0])"
            "    return tr.getAttribute('data-status');"
            "return null;",
            peer,
        )
        return found

    def cell(self, peer: str, item: str) -> dict[str, Any] | None:
        found: dict[str, Any] | None = self.js(
            "for (const tr of document.querySelectorAll('#matrix tbody tr')) {"
            "  if (tr.getAttribute('data-peer') !== arguments[0]) continue;"
            "  for (const td of tr.querySelectorAll('td'))"
            "    if (td.getAttribute('data-item') === arguments[1])"
            "      return {how: td.getAttribute('data-how'),"
            "              at: Number(td.getAttribute('data-shown-at'))};"
            "}"
            "return null;",
            peer,
            item,
        )
        return found

    def texts(self, selector: str) -> list[str]:
        found: list[str] = self.js(
            "return [...document.querySelectorAll(arguments[0])].map(e => e.textContent);",
            selector,
        )
        return found

    def dropped(self) -> dict[str, list[str]]:
        """What the page says was dropped, by why: the count's line and the reasons kept."""
        found: dict[str, list[str]] = self.js(
            "const out = {};"
            "for (const li of document.querySelectorAll('#dropped li'))"
            "  out[li.getAttribute('data-why')] ="
            "    [...li.querySelectorAll('span')].map(e => e.textContent);"
            "return out;"
        )
        return found

    def stat(self, name: str) -> str:
        return str(self.js("return document.getElementById(arguments[0]).textContent;", name))


@pytest.fixture
def fleet(tmp_path: Path) -> Iterator[tuple[Page, int, ExitStack]]:
    """A teacher serving the colours (publishing events), the monitor, and the page open."""
    port, http = free_port(), free_port()
    with ExitStack() as stack:
        stack.enter_context(serving(port, "--publish-events", name="t"))
        stack.enter_context(
            ktbt_process(
                "monitor", "--connect", endpoint(port), "--http", f"127.0.0.1:{http}",
                ready="localhost only",
            )
        )  # fmt: skip
        url = f"http://127.0.0.1:{http}/"
        assert wait_until(lambda: _up(url), 15)
        driver = stack.enter_context(chromium())
        driver.get(url)
        yield Page(driver), port, stack


def test_peers_transfers_refusals_and_departures_show_live(
    fleet: tuple[Page, int, ExitStack], tmp_path: Path
) -> None:
    page, port, stack = fleet
    assert wait_until(lambda: page.status("t") == "present", 15)
    assert wait_until(
        lambda: (page.cell("t", sequence_digest(GREEN)) or {}).get("how") == "known", 15
    )

    # A learner: the merge in its transfer log, and the cell's drawing in the page; selected,
    # its control tree, asked of it, with the learned item merged in.
    log = tmp_path / "r1.log"
    with ktbt_process(
        "peer", "run", "--id", "r1", "--connect", endpoint(port), "--log", str(log),
        "--sequence", "TargetSeen(colour=2)", "--duration", "60", "--publish-events",
        ready="r1: learned",
    ):  # fmt: skip
        merged = next(
            json.loads(line) for line in log.read_text().splitlines() if '"merged"' in line
        )
        assert wait_until(
            lambda: (page.cell("r1", sequence_digest(GREEN)) or {}).get("how") == "learned", 5
        )
        cell = page.cell("r1", sequence_digest(GREEN))
        assert cell is not None
        lag = cell["at"] - _ms(merged["t"])
        assert lag <= 1000, f"shown {lag} ms after the merge"
        whos = page.js(
            "return [...document.querySelectorAll('#transfers li')]"
            "  .map(li => [...li.querySelectorAll('.who')].map(e => e.textContent));"
        )
        assert ["t", "r1"] in whos, whos
        page.js("document.querySelector('#matrix tbody tr[data-peer=r1] th').click();")

        def control() -> str:
            return page.stat("detail-control")

        assert wait_until(lambda: "TargetSeen(colour=2)" in control(), 10), control()
        # The demo tree's placeholder, empty before the merge, holds the item now.
        assert "Knowledge [new]" in control() and "[new] (empty)" not in control(), control()
        assert page.js("return document.getElementById('detail-control').children.length") == 0

    # A teacher whose answer breaks the learner's registry: refused, with the learner's reason.
    bad = tmp_path / "bad.sbt"
    bad.write_text(BAD)
    log2 = tmp_path / "r2.log"
    stack.enter_context(
        ktbt_process("peer", "serve", "--id", "bad", "--knowledge", str(bad), "--connect",
                     endpoint(port), ready="serving")
    )  # fmt: skip
    assert wait_until(lambda: page.status("bad") == "present", 15)  # the matrix is rebuilt
    assert (
        page.cell("r1", sequence_digest(GREEN)) == cell
    )  # first shown when it was, not at the rebuild
    with ktbt_process(
        "peer", "run", "--id", "r2", "--connect", endpoint(port), "--log", str(log2),
        "--sequence", "Carrying", "--duration", "4", "--publish-events",
    ) as robot:  # fmt: skip
        robot.wait(timeout=60)
    reasons = [
        json.loads(line)["reason"] for line in log2.read_text().splitlines() if '"refused"' in line
    ]
    assert reasons and "SBT310" in reasons[0]

    def refusal_shown() -> bool:
        return any(reasons[0] in t and "r2" in t for t in page.texts("#refusals li"))

    assert wait_until(refusal_shown, 5), page.texts("#refusals li")

    # A killed peer is marked gone.
    victim = stack.enter_context(
        ktbt_process("peer", "serve", "--id", "victim", "--knowledge",
                     str(ROOT / "examples" / "knowledge" / "colours.sbt"),
                     "--connect", endpoint(port), ready="serving")
    )  # fmt: skip
    assert wait_until(lambda: page.status("victim") == "present", 15)
    page.js("window.row = document.querySelector('#matrix tbody tr[data-peer=victim]')")
    victim.send_signal(signal.SIGKILL)
    victim.wait(timeout=10)
    assert wait_until(lambda: page.status("victim") == "gone", 20)
    assert page.js("return window.row.isConnected")  # its row updated, not the matrix rebuilt
    assert page.status("t") == "present"
    assert int(page.stat("stat-gone")) == 3  # r1 and r2 left too


def test_hostile_names_items_and_reasons_stay_text_and_junk_is_counted(
    fleet: tuple[Page, int, ExitStack],
) -> None:
    import zenoh

    from ktbt_proto.transport.zenoh import ZenohSettings, open_session

    page, port, _ = fleet
    hostile_id = "<img src=x onerror=window.pwned=1>"
    item = '<c>(TargetSeen,note="<script>window.pwned=2</script>")'
    reason = "<b>bold</b><img src=x onerror=window.pwned=3>"
    session = open_session(ZenohSettings(connect=[endpoint(port)]))
    try:
        token = session.liveliness().declare_token(f"ktbt/v1/peers/{hostile_id}")
        events = session.declare_publisher("ktbt/v1/events/h")
        now = datetime.now().astimezone().isoformat(timespec="milliseconds")

        def event(n: int, **fields: Any) -> bytes:
            return encode_event(FleetEvent(peer="h", n=n, t=now, **fields))

        def event_of(peer: str, n: int, sequence: str) -> bytes:
            one = FleetEvent(
                peer=peer,
                n=n,
                t=now,
                event="merged",
                item=sequence_digest(sequence),
                sequence=sequence,
            )
            return encode_event(one)

        # connected, and the token's name, not a peer name, refused
        assert wait_until(lambda: "malformed" in page.dropped(), 10)
        events.put(event(0, event="merged", item=sequence_digest(item), sequence=item, teacher="t"))
        events.put(event(1, event="refused", reason=reason))
        assert wait_until(lambda: any(reason in t for t in page.texts("#refusals li")), 10)
        assert wait_until(
            lambda: (page.cell("h", sequence_digest(item)) or {}).get("how") == "learned", 5
        )

        junk = [b"not json", b"{" * 20_000, event(2, event="merged").replace(b'"h"', b'"x"')]
        for payload in junk:
            events.put(payload)
        flood = session.declare_publisher(  # every one sent: the monitor must drop them
            "ktbt/v1/events/f", congestion_control=zenoh.CongestionControl.BLOCK
        )
        for n in range(3000):
            flood.put(encode_event(FleetEvent(peer="f", n=n, t=now, event="query-sent")))
        assert wait_until(lambda: int(page.stat("stat-dropped")) >= len(junk) + 500, 10), page.js(
            "return document.getElementById('stat-dropped').title"
        )
        dropped = page.js("return document.getElementById('stat-dropped').title")
        assert all(why in dropped for why in ("malformed", "oversized", "wrong key", "flood"))
        # A signed peer, then an event of its name under another key, and a replay.
        me, mallory = Identity.generate(), Identity.generate()

        def signed(n: int, who: Identity) -> bytes:
            one = FleetEvent(peer="s", n=n, t=now, event="query-sent", key=who.public)
            return encode_event(one.model_copy(update={"sig": who.sign(signed_bytes(one))}))

        own = session.declare_publisher("ktbt/v1/events/s")
        own.put(signed(0, me))
        own.put(signed(1, mallory))
        own.put(signed(0, me))
        assert wait_until(lambda: {"forged", "replayed"} <= set(page.dropped()), 10)
        assert any(mallory.public in r for r in page.dropped()["forged"])
        own.undeclare()  # type: ignore[no-untyped-call]
        flood.undeclare()  # type: ignore[no-untyped-call]
        events.undeclare()  # type: ignore[no-untyped-call]
        token.undeclare()  # type: ignore[no-untyped-call]
    finally:
        session.close()  # type: ignore[no-untyped-call]

    assert page.js("return window.pwned === undefined")
    assert page.js("return document.querySelectorAll('img, b, script:not([src])').length") == 0
    assert hostile_id not in page.texts("#matrix th.peer-name")
    assert any(hostile_id in r for r in page.dropped()["malformed"])  # as text
    assert any('note="<script>' in t for t in page.texts("#matrix th.item"))

    # A full items table (512): an item evicted leaves the page's timeline too.
    session = open_session(ZenohSettings(connect=[endpoint(port)]))
    try:
        filler = session.declare_publisher(
            "ktbt/v1/events/e", congestion_control=zenoh.CongestionControl.BLOCK
        )
        fill = [f"<c>(E{k},x={k})" for k in range(520)]
        for n, sequence in enumerate(fill):
            filler.put(event_of("e", n, sequence))
        assert wait_until(lambda: page.js("return window.ktbtMonitor.itemCount()") == 512, 15)
        assert sequence_digest(fill[0]) in page.js("return window.ktbtMonitor.timelineItems()")
        newcomer = session.declare_publisher("ktbt/v1/events/g")
        newcomer.put(event_of("g", 0, "<c>(G0)"))  # e is the heaviest: its oldest goes
        lines = "return window.ktbtMonitor.timelineItems()"
        assert wait_until(lambda: sequence_digest(fill[0]) not in page.js(lines), 10)
        assert len(page.js(lines)) <= page.js("return window.ktbtMonitor.itemCount()") == 512
    finally:
        session.close()  # type: ignore[no-untyped-call]


def test_the_page_is_served_with_its_policy_and_only_to_its_own_host(
    fleet: tuple[Page, int, ExitStack],
) -> None:
    page, _, _ = fleet
    url = page.driver.current_url
    with urllib.request.urlopen(url, timeout=5) as reply:
        policy = reply.headers["Content-Security-Policy"]
    assert "script-src 'self'" in policy and "frame-ancestors 'none'" in policy
    assert "unsafe-inline" not in policy
    evil = urllib.request.Request(url, headers={"Host": "evil.example"})
    with pytest.raises(urllib.error.HTTPError) as refused:
        urllib.request.urlopen(evil, timeout=5)
    assert refused.value.code == 400


@pytest.mark.slow
@pytest.mark.network
def test_a_fleet_started_by_ktbt_fleet_run_shows_in_the_page(tmp_path: Path) -> None:
    """``ktbt fleet run --monitor``: the page shows every peer and, once the fleet has
    converged, every item known by every peer; the run's own check agrees, and the monitor
    goes when the run ends."""
    out, http, printed = tmp_path / "run", free_port(), tmp_path / "printed.txt"
    url = f"http://127.0.0.1:{http}/"
    record = out / "events.jsonl"
    with chromium() as driver:  # started first: the page must be read before the run ends
        with open(printed, "w") as sink:
            proc = subprocess.Popen(
                [sys.executable, "-m", "ktbt_proto", "fleet", "run", "--peers", "5",
                 "--seed", "2", "--settle", "10", "--monitor", f"127.0.0.1:{http}", "--no-live",
                 "--out", str(out)],
                cwd=ROOT, stdout=sink, stderr=subprocess.STDOUT, text=True,
            )  # fmt: skip
        try:
            assert wait_until(lambda: _up(url), 60), printed.read_text()
            driver.get(url)
            page = Page(driver)
            assert wait_until(lambda: record.exists() and '"run"' in record.read_text(), 30)
            run = json.loads(record.read_text().splitlines()[0])
            items = [sequence_digest(k) for k in run["items"]]
            peers = [n["name"] for n in run["plan"]["nodes"]]

            def everyone_knows_everything() -> bool:
                cells = [page.cell(p, i) for p in peers for i in items]
                return all(c is not None and c["how"] in ("learned", "known") for c in cells)

            assert wait_until(everyone_knows_everything, 60), printed.read_text()
            assert {page.status(p) for p in peers} == {"present"}
            proc.wait(timeout=90)
        finally:
            _, left, ours = sweep(proc, record, printed.read_text())
    assert not left and not ours, (left, ours)
    summary = json.loads((out / "summary.json").read_text())
    verdicts = {v["name"]: v["status"] for v in summary["verdicts"]}
    assert verdicts["the monitor shows what the peers know"] == "pass", summary["verdicts"]
    assert proc.returncode == 0, printed.read_text()
    assert not _up(url)  # the monitor ended with the run
