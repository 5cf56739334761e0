"""The live targets' change notifications: one tracker frame wakes the streams once, and every
stream of a version sends the same text."""

from __future__ import annotations

import json

from server.api.targets import _positions_message
from server.services.targets import LiveTargets


def _update(live: LiveTargets, track_id: int, x: float) -> None:
    live.update(
        None,
        track_id,
        label=None,
        kind="person",
        state="confirmed",
        first_seen=0.0,
        t=1.0,
        xy=[x, 1.0],
        cov=[[0.01, 0.0], [0.0, 0.01]],
    )


def test_a_batch_of_changes_wakes_the_watchers_once(client):
    live = LiveTargets(client.app.state.runtime.session_factory)
    woken = []
    live.watch(lambda: woken.append(live.version))
    _update(live, 1, 1.0)
    assert woken == [1]
    with live.batch():
        _update(live, 1, 1.1)
        _update(live, 2, 2.0)
        with live.batch():  # nested: still one wake, at the outer end
            live.set_state(None, 2, "coasting")
        assert woken == [1]
    assert woken == [1, 4]
    # Every change still counts in the version the streams compare with.
    assert live.version == 4


def test_one_encoding_per_version_with_the_targets_of_that_version(client):
    live = LiveTargets(client.app.state.runtime.session_factory)
    _update(live, 1, 1.0)
    v1, text1 = _positions_message(live)
    assert _positions_message(live) == (v1, text1)
    assert _positions_message(live)[1] is text1  # the same object: encoded once
    _update(live, 1, 2.0)
    v2, text2 = _positions_message(live)
    assert v2 == v1 + 1
    message = json.loads(text2)
    assert message["type"] == "positions" and message["t"] == 1.0
    assert [t["xy"] for t in message["targets"]] == [[2.0, 1.0]]
