"""`<prefix>/available` with two service processes on one PostgreSQL database and a real broker
(spec 09), the test's own (the app run by a TestClient, as the other server tests run it) and an
`intspace serve` started as a user starts it. One process at a time publishes the topic, chosen
by an advisory lock as a space's tracker is. The owner stopped cleanly hands it over without a
word (the home never hears `offline` while another process serves); the new owner answers a
late last will (`offline` from a peer the broker noticed late) with `online`, and, killed,
leaves its own last will: `offline`, nobody serving any more."""

from __future__ import annotations

import os
import signal
import time

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from server.services.comms.home import AVAILABLE_KEY
from server.services.ownership import NAMESPACE
from tests.support.advisory_locks import lock_holder
from tests.support.mqtt_broker import broker, subscribe  # noqa: F401
from tests.support.service import WITHOUT_TWIN, Service, start_service
from tests.support.waiting import wait_until

TOPIC = "intspace/available"
TOKEN = "home-processes-admin-token"


def _available_owner(database_url: str) -> int | None:
    """Return the process id holding the availability's advisory lock, None when nobody does."""
    return lock_holder(
        database_url,
        "l.classid = :ns AND l.objid = :key AND l.objsubid = 2",
        {"ns": NAMESPACE, "key": AVAILABLE_KEY & 0xFFFFFFFF},
    )


@pytest.mark.parametrize("database_url", ["postgresql"], indirect=True)
def test_availability_follows_the_processes(
    database_url,
    broker,  # noqa: F811
    make_settings,
    tmp_path,
    monkeypatch,
):
    monkeypatch.setenv("INTSPACE_MQTT_URL", broker.url)
    sub, rec = subscribe(broker, TOPIC)

    def said(payload: bytes, since: float) -> list[float]:
        return [t for t, tp, p, _ in rec.on(lambda tp: tp == TOPIC) if p == payload and t >= since]

    # This process's service starts first and takes the topic; the other starts meanwhile.
    serve: Service | None = None
    try:
        with TestClient(create_app(make_settings(mqtt_url=broker.url))):
            wait_until(
                lambda: _available_owner(database_url) == os.getpid(),
                what="this process owning the topic",
                stalled_after_s=5,
            )
            assert rec.wait(lambda: rec.latest(TOPIC) == b"online", 5)
            start = time.monotonic()
            # The twin and the 3D scene run in one designated process; the other runs neither.
            env = {"INTSPACE_DATABASE_URL": database_url, "INTSPACE_MQTT_URL": broker.url}
            serve = start_service(tmp_path, token=TOKEN, env={**env, **WITHOUT_TWIN})
            print(f"the other process ready in {time.monotonic() - start:.1f} s")
            assert _available_owner(database_url) == os.getpid()
            stopped = time.time()
        # A clean stop of the owner: the other takes the topic over, nobody says offline.
        print(f"the owner stopped in {time.time() - stopped:.1f} s")
        other = serve.process.pid
        wait_until(
            lambda: _available_owner(database_url) == other,
            what="the other process owning the topic",
            stalled_after_s=5,
        )
        # The new owner reconnected with its last will and said it is online.
        assert rec.wait(lambda: bool(said(b"online", stopped)), 5), rec.on(lambda tp: tp == TOPIC)
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
        assert serve.kill() == -signal.SIGKILL
        assert rec.wait(lambda: bool(said(b"offline", killed)), 5), "no last will"
        assert rec.latest(TOPIC) == b"offline"
    finally:
        if serve is not None:
            serve.stop()
        sub.loop_stop()
        sub.disconnect()
