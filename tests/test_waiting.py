"""The shared wait (tests/support/waiting.py): it lasts as long as the work advances, past any
total time, and fails once the reported progress stays the same for the stated time."""

from __future__ import annotations

import time

import pytest

from tests.support.waiting import Stalled, wait_for_run


def _run(status, stage=None, fraction=None):
    progress = None if stage is None else {"stage": stage, "fraction": fraction}
    return {"status": status, "attempts": 1, "progress": progress}


def test_a_run_that_advances_is_waited_for_past_the_stall_time():
    # 12 reads 0.05 s apart (0.6 s in all), each a new fraction: longer than the 0.3 s
    # allowed without progress, which no single step comes near.
    reads = iter([_run("running", "driving", k / 12) for k in range(12)] + [_run("succeeded")])
    started = time.monotonic()
    run = wait_for_run(lambda: next(reads), stalled_after_s=0.3, poll_s=0.05)
    assert run["status"] == "succeeded"
    assert time.monotonic() - started > 0.3


def test_a_run_whose_progress_stops_fails_after_the_stated_time():
    reads = iter([_run("queued"), _run("running", "driving", 0.1)])
    last = _run("running", "driving", 0.2)
    started = time.monotonic()
    with pytest.raises(Stalled, match=r"no progress for 0.3 s .*'driving', 0\.2"):
        wait_for_run(lambda: next(reads, last), stalled_after_s=0.3, poll_s=0.02)
    # It failed after the stated time without progress, not before, nor much after.
    assert 0.3 <= time.monotonic() - started < 1.5
