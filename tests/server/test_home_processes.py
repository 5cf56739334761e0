"""`<prefix>/available` with two `intspace serve` processes on one PostgreSQL database and a real
broker (spec 09): one process at a time publishes it, chosen by an advisory lock as a space's
tracker is. The owner stopped cleanly hands it over without a word (the home never hears
`offline` while another process serves); the new owner answers a late last will (`offline` from
a peer the broker noticed late) with `online`, and, killed, leaves its own last will: `offline`,
nobody serving any more."""

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

    # Started together (start-up takes seconds).
    start = time.monotonic()
    procs = [Serve(database_url, tmp_path, tmp_path / f"serve{i}.log") for i in range(2)]
    try:
        for p in procs:
            p.wait_ready()
        print(f"two processes ready in {time.monotonic() - start:.1f} s")
        pids = {p.proc.pid: p for p in procs}
        first = pids[_wait(lambda: _available_owner(database_url), 5, "an owner")]
        second = next(p for p in procs if p is not first)
        assert rec.wait(lambda: rec.latest(TOPIC) == b"online", 5)

        # A clean stop of the owner: the other takes the topic over, nobody says offline.
        stopped = time.time()
        first.stop()
        print(f"the owner stopped in {time.time() - stopped:.1f} s")
        _wait(lambda: _available_owner(database_url) == second.proc.pid, 5, "the second owner")
        time.sleep(1.0)  # the new owner's reconnection with its last will has landed
        assert said(b"offline", stopped) == [], rec.on(lambda tp: tp == TOPIC)
        assert rec.latest(TOPIC) == b"online"

        # A last will that reaches the broker late (a peer it noticed only after its
        # keep-alive): the owner says online again (it listens to the topic).
        late = time.time()
        sub.publish(TOPIC, "offline", qos=1, retain=True)
        assert rec.wait(lambda: bool(said(b"online", late)), 3), rec.on(lambda tp: tp == TOPIC)
        assert rec.latest(TOPIC) == b"online"

        # The owner killed, nobody left: its own last will (set when it took over) says offline.
        killed = time.time()
        second.kill()
        assert rec.wait(lambda: bool(said(b"offline", killed)), 5), "no last will"
        assert rec.latest(TOPIC) == b"offline"
    finally:
        for p in procs:
            p.stop()
        sub.loop_stop()
        sub.disconnect()
