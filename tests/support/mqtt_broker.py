"""A real MQTT broker for the tests: Debian's mosquitto on a free loopback port, with a temporary
configuration (a user and password, no persistence), that a test can stop and start again on
the same port; and a subscriber that records what the broker delivers."""

from __future__ import annotations

import getpass
import os
import shutil
import socket
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import paho.mqtt.client as paho
import pytest

from tests.support.ports import free_port

MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
MOSQUITTO_PASSWD = shutil.which("mosquitto_passwd") or "/usr/bin/mosquitto_passwd"
USER, PASSWORD = "intspace", "s3cret-Broker-pw"


class Broker:
    """A mosquitto process on 127.0.0.1:`port` requiring USER / PASSWORD."""

    def __init__(self, directory: Path) -> None:
        self.port = free_port()
        self.dir = directory
        passwords = directory / "passwords"
        subprocess.run(
            [MOSQUITTO_PASSWD, "-c", "-b", str(passwords), USER, PASSWORD],
            check=True,
            capture_output=True,
        )
        os.chmod(passwords, 0o600)
        self.config = directory / "mosquitto.conf"
        self.config.write_text(
            f"listener {self.port} 127.0.0.1\n"
            # Started as root, mosquitto would drop to the "mosquitto" user, who cannot read
            # the test's temporary directory: it stays the user running the tests.
            f"user {getpass.getuser()}\n"
            "allow_anonymous false\n"
            f"password_file {passwords}\n"
            "persistence false\n"
            "log_dest stderr\n"
            "log_type error\n"
        )
        self.process: subprocess.Popen[bytes] | None = None

    @property
    def url(self) -> str:
        return f"mqtt://{USER}:{PASSWORD}@127.0.0.1:{self.port}"

    def start(self) -> None:
        self.process = subprocess.Popen(
            [MOSQUITTO, "-c", str(self.config)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
        )
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", self.port)) == 0:
                    return
            if self.process.poll() is not None:
                err = self.process.stderr.read().decode() if self.process.stderr else ""
                raise RuntimeError(f"mosquitto exited: {err}")
            time.sleep(0.02)
        raise RuntimeError("mosquitto did not listen within 10 s")

    def kill(self) -> None:
        if self.process is not None:
            self.process.kill()
            self.process.wait(5)
            self.process = None


@pytest.fixture
def broker(tmp_path: Path):
    """Yield a running mosquitto broker (stopped at the end)."""
    if not os.path.exists(MOSQUITTO):
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail("mosquitto is not installed (CI=true requires it)")
        pytest.skip("mosquitto is not installed")
    b = Broker(tmp_path)
    b.start()
    yield b
    b.kill()


@dataclass
class Recorder:
    """What a subscriber received: (arrival time, topic, payload, retained) in order."""

    messages: list[tuple[float, str, bytes, bool]] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def latest(self, topic: str) -> bytes | None:
        with self.lock:
            for _, t, p, _ in reversed(self.messages):
                if t == topic:
                    return p
        return None

    def on(self, topic_filter: Callable[[str], bool]) -> list[tuple[float, str, bytes, bool]]:
        with self.lock:
            return [m for m in self.messages if topic_filter(m[1])]

    def wait(self, check: Callable[[], bool], timeout: float = 5.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if check():
                return True
            time.sleep(0.02)
        return check()


def subscribe(broker: Broker, topics: str | list[str] = "#") -> tuple[paho.Client, Recorder]:
    """Return a connected paho client subscribed to `topics` (reconnecting on its own) and its
    recorder."""
    rec = Recorder()
    client = paho.Client(paho.CallbackAPIVersion.VERSION2)
    client.username_pw_set(USER, PASSWORD)
    filters = [topics] if isinstance(topics, str) else topics

    def on_connect(c, userdata, flags, reason, properties):
        for f in filters:
            c.subscribe(f, qos=1)

    def on_message(c, userdata, msg):
        with rec.lock:
            rec.messages.append((time.time(), msg.topic, bytes(msg.payload), bool(msg.retain)))

    client.on_connect = on_connect
    client.on_message = on_message
    client.reconnect_delay_set(0.1, 0.5)
    client.connect("127.0.0.1", broker.port)
    client.loop_start()
    return client, rec
