"""How a long-running ``ktbt`` command hears SIGINT and SIGTERM (``tools.peer.until_signalled``):
its event is set by a thread of its own, never by the Python signal handler, which runs in the
main thread between two of its bytecodes. A signal that comes while the main thread holds the
event's lock (inside ``Event.wait``) is acted on once the lock is free; a handler that set the
event itself would wait for that lock for ever. And a burst of SIGTERMs ends a real ``ktbt
peer serve``, which a second SIGTERM during the first one's handling once left running."""

from __future__ import annotations

import os
import signal
import threading

import pytest

from ktbt_proto.tools.peer import until_signalled
from tests.zenoh_helpers import ROOT, endpoint, free_port, ktbt_process


def test_a_signal_while_the_main_thread_holds_the_events_lock_is_acted_on_once_it_is_free() -> None:
    before = signal.getsignal(signal.SIGTERM)
    woken = threading.Event()
    with until_signalled([woken]) as stop:
        with stop._cond:  # type: ignore[attr-defined]  # held, as inside stop.wait()
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(1000):  # bytecodes: the Python handler runs between two of them
                pass
            assert not stop.is_set()  # not set here, and nothing waits for this lock
        assert stop.wait(30) and woken.wait(30)
    assert signal.getsignal(signal.SIGTERM) is before  # given back as it was


@pytest.mark.network
def test_a_burst_of_sigterms_ends_a_serving_peer() -> None:
    knowledge = str(ROOT / "examples" / "knowledge" / "colours.sbt")
    for trial in range(5):
        args = ["peer", "serve", "--id", f"t{trial}", "--knowledge", knowledge,
                "--listen", endpoint(free_port())]  # fmt: skip
        with ktbt_process(*args, ready="serving") as proc:
            for _ in range(20):
                proc.send_signal(signal.SIGTERM)
            assert proc.wait(timeout=30) == 0
