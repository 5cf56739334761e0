"""`<prefix>/available` with several `intspace serve` processes on one PostgreSQL database and a
real broker (spec 09): one process at a time publishes it, chosen by an advisory lock as a
space's tracker is. The owner stopped cleanly hands it over without a word (the home never hears
`offline` while another process serves); the next owner killed, its last will says `offline` and
the survivor says `online` again within seconds; the last process stopped says `offline`."""

from __future__ import annotations

import time

import pytest
from sqlalchemy import create_engine, text

from server.services.home import AVAILABLE_KEY
from server.services.ownership import APPLICATION_NAME, NAMESPACE
from tests.server.mqtt_broker import broker, subscribe  # noqa: F401
from tests.server.test_multiprocess import Serve

TOPIC = "intspace/available"


def _available_owner(database_url: str) -> int | None:
    """Return the process id holding the availability's advisory lock, None when nobody does."""
    engine = create_engine(database_url)
    try:
        with engine.connect() as c:
            name = c.execute(
                text(
                    "SELECT a.application_name FROM pg_locks l JOIN pg_stat_activity a "
                    "USING (pid) WHERE l.locktype = 'advisory' AND l.classid = :ns "
                    "AND l.objid = :key AND l.objsubid = 2 AND l.granted"
                ),
                {"ns": NAMESPACE, "key": AVAILABLE_KEY & 0xFFFFFFFF},
            ).scalar()
    finally:
        engine.dispose()
    if name is None:
        return None
    assert name.startswith(APPLICATION_NAME + ":")
    return int(name.split(":")[1])


def _wait(predicate, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.05)


@pytest.mark.parametrize("database_url", ["postgresql"], indirect=True)
def test_availability_follows_the_processes(database_url, broker, tmp_path, monkeypatch):  # noqa: F811
    monkeypatch.setenv("INTSPACE_MQTT_URL", broker.url)
    sub, rec = subscribe(broker, TOPIC)

    def said(payload: bytes, since: float) -> list[float]:
        return [t for t, tp, p, _ in rec.on(lambda tp: tp == TOPIC) if p == payload and t >= since]

    # Started together (start-up takes seconds); the third is the survivor at the end.
    start = time.monotonic()
    procs = [Serve(database_url, tmp_path, tmp_path / f"serve{i}.log") for i in range(3)]
    try:
        for p in procs:
            p.wait_ready()
        print(f"three processes ready in {time.monotonic() - start:.1f} s")
        pids = {p.proc.pid: p for p in procs}
        first = pids[_wait(lambda: _available_owner(database_url), 5, "an owner")]
        assert rec.wait(lambda: rec.latest(TOPIC) == b"online", 5)

        # A clean stop of the owner: another process takes the topic over, nobody says offline.
        stopped = time.time()
        first.stop()
        print(f"the owner stopped in {time.time() - stopped:.1f} s")
        second = pids[
            _wait(
                lambda: (o := _available_owner(database_url)) not in (None, first.proc.pid) and o,
                5,
                "a second owner",
            )
        ]
        time.sleep(1.5)  # the stopped process's last messages and the new owner's have landed
        assert said(b"offline", stopped) == [], rec.on(lambda tp: tp == TOPIC)
        assert rec.latest(TOPIC) == b"online"

        # The owner killed: its last will says offline, the survivor says online again (within
        # its second's poll for the free lock, plus its reconnection with its own last will).
        third = next(p for p in procs if p is not first and p is not second)
        killed = time.time()
        second.kill()
        assert rec.wait(lambda: bool(said(b"offline", killed)), 5), "no last will"
        assert rec.wait(lambda: bool(said(b"online", said(b"offline", killed)[0])), 5)
        back = said(b"online", said(b"offline", killed)[0])[0] - killed
        print(f"available again {back:.2f} s after the owner was killed")
        assert _available_owner(database_url) == third.proc.pid

        # The last process stopped: offline.
        last = time.time()
        third.stop()
        print(f"the last process stopped in {time.time() - last:.1f} s")
        assert rec.wait(lambda: bool(said(b"offline", last)), 5)
        assert rec.latest(TOPIC) == b"offline"
    finally:
        for p in procs:
            p.stop()
        sub.loop_stop()
        sub.disconnect()
