"""The MQTT connection against a real broker (mosquitto): retained states and messages
delivered, the password never shown, a bounded queue while the broker is away, and the retained
states back within 5 s of the broker's return after it was killed."""

from __future__ import annotations

import logging
import time

import pytest

from server.services.mqtt import BrokerUrl, BrokerUrlError, MqttLink
from tests.server.mqtt_broker import PASSWORD, broker, subscribe  # noqa: F401


def test_broker_url_parsing_and_redaction():
    url = BrokerUrl.parse("mqtts://bob:p%40ss@broker.local")
    assert (url.host, url.port, url.tls, url.username, url.password) == (
        "broker.local",
        8883,
        True,
        "bob",
        "p@ss",
    )
    assert url.redacted() == "mqtts://bob:***@broker.local:8883"
    assert BrokerUrl.parse("mqtt://h").redacted() == "mqtt://h:1883"
    for bad in ("http://u:Zq9x@h", "mqtt://u:Zq9x@", "mqtt://u:Zq9x@h:99999", "mqtt://u:Zq9x@h/x"):
        with pytest.raises(BrokerUrlError) as info:
            BrokerUrl.parse(bad)
        assert "Zq9x" not in str(info.value)


def test_retained_and_messages_reach_the_broker(broker, caplog):  # noqa: F811
    caplog.set_level(logging.DEBUG)
    link = MqttLink(BrokerUrl.parse(broker.url), will=("t/available", "offline"))
    link.start()
    client, rec = subscribe(broker, "t/#")
    try:
        link.retain("t/available", "online")
        link.retain("t/zone", "3")
        link.publish("t/events", '{"type": "enter"}')
        assert rec.wait(lambda: rec.latest("t/events") is not None)
        assert rec.latest("t/zone") == b"3" and rec.latest("t/available") == b"online"
        status = link.status()
        assert status["connected"] and status["dropped"] == 0
        assert PASSWORD not in str(status) and status["url"].endswith(
            f":***@127.0.0.1:{broker.port}"
        )
        link.retain("t/zone", b"")  # cleared: forgotten once the broker has it
        assert rec.wait(lambda: rec.latest("t/zone") == b"")
        assert rec.wait(lambda: link.retained("t/zone") is None)
    finally:
        link.stop(final=[("t/available", "offline")])
        assert rec.wait(lambda: rec.latest("t/available") == b"offline")
        client.loop_stop()
        client.disconnect()
    assert PASSWORD not in caplog.text


def test_broker_killed_and_restarted(broker, caplog):  # noqa: F811
    link = MqttLink(BrokerUrl.parse(broker.url), queue_limit=50)
    link.start()
    try:
        link.retain("s/occupancy", "1")
        deadline = time.monotonic() + 5
        while not link.status()["connected"] and time.monotonic() < deadline:
            time.sleep(0.02)
        broker.kill()
        deadline = time.monotonic() + 5
        while link.status()["connected"] and time.monotonic() < deadline:
            time.sleep(0.02)
        assert not link.status()["connected"]
        # Away: 200 events fill the queue of 50; the oldest 150 are dropped and counted.
        for k in range(200):
            link.publish("s/events", str(k))
        link.retain("s/occupancy", "2")
        status = link.status()
        assert status["queued"] == 50 and status["dropped"] == 150
        # The broker returns without persistence: it has lost every retained topic.
        time.sleep(1.0)
        broker.start()
        back = time.monotonic()
        client, rec = subscribe(broker, "s/#")
        try:
            assert rec.wait(lambda: rec.latest("s/occupancy") == b"2", timeout=5.0)
            took = time.monotonic() - back
            print(f"retained state back {took:.2f} s after the broker's return")
            assert took < 5.0
            # The queued events follow, the newest 50, in order.
            assert rec.wait(lambda: len(rec.on(lambda t: t == "s/events")) == 50)
            got = [int(p) for _, _, p, _ in rec.on(lambda t: t == "s/events")]
            assert got == list(range(150, 200))
        finally:
            client.loop_stop()
            client.disconnect()
        assert link.status()["connections"] == 2 and link.status()["queued"] == 0
    finally:
        link.stop()
    assert PASSWORD not in caplog.text
