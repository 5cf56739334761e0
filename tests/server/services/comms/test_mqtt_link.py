"""The MQTT connection against a real broker (mosquitto): retained states and messages
delivered, the password never shown, a bounded queue while the broker is away, and the retained
states back within 5 s of the broker's return after it was killed (the link reaches it through
a gate the test opens once its own subscriber is on the restarted broker)."""

from __future__ import annotations

import logging
import socket
import threading
import time

import pytest

from server.services.comms.mqtt import BrokerUrl, BrokerUrlError, MqttLink
from tests.support.mqtt_broker import PASSWORD, broker, subscribe  # noqa: F401


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


class Gate:
    """A TCP forwarder from a loopback port of its own to the broker's. Shut, it listens no
    more (a connection is refused, as by a broker that is not back yet), so that a test's
    subscriber can be on the restarted broker before the link under test is."""

    def __init__(self, target_port: int) -> None:
        self.target = target_port
        self.port = 0
        self.server: socket.socket | None = None
        self.reopen()

    def reopen(self) -> None:
        self.server = socket.create_server(("127.0.0.1", self.port))
        self.port = self.server.getsockname()[1]
        threading.Thread(target=self._accept, args=(self.server,), daemon=True).start()

    def shut(self) -> None:
        if self.server is not None:
            # shutdown first: a close alone leaves the socket listening while the accepting
            # thread is blocked on it.
            try:
                self.server.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            self.server.close()
            self.server = None

    def _accept(self, server: socket.socket) -> None:
        while True:
            try:
                down, _ = server.accept()
            except OSError:
                return  # shut
            try:
                up = socket.create_connection(("127.0.0.1", self.target), timeout=2)
            except OSError:
                down.close()  # the broker is away: so is the connection
                continue
            for a, b in ((down, up), (up, down)):
                threading.Thread(target=self._pump, args=(a, b), daemon=True).start()

    @staticmethod
    def _pump(src: socket.socket, dst: socket.socket) -> None:
        try:
            while data := src.recv(65536):
                dst.sendall(data)
        except OSError:
            pass
        for s in (src, dst):
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            s.close()


def test_broker_killed_and_restarted(broker, caplog):  # noqa: F811
    gate = Gate(broker.port)
    url = BrokerUrl.parse(broker.url.replace(f":{broker.port}", f":{gate.port}"))
    link = MqttLink(url, queue_limit=50)
    link.start()
    try:
        link.retain("s/occupancy", "1")
        deadline = time.monotonic() + 5
        while not link.status()["connected"] and time.monotonic() < deadline:
            time.sleep(0.02)
        broker.kill()
        gate.shut()
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
        # The broker returns without persistence: it has lost every retained topic. A
        # subscriber is on it (its own message back says it is subscribed) before the link can
        # reach it: the events the link sends on its return are not lost to a late subscriber.
        time.sleep(1.0)  # the outage itself: time must pass with the broker away
        broker.start()
        client, rec = subscribe(broker, "s/#")
        try:
            deadline = time.monotonic() + 5
            while rec.latest("s/probe") is None and time.monotonic() < deadline:
                client.publish("s/probe", "1", qos=1)
                time.sleep(0.1)
            assert rec.latest("s/probe") is not None
            gate.reopen()
            back = time.monotonic()
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
        gate.shut()
    assert PASSWORD not in caplog.text
