"""Waiting on work that reports its progress (calibration runs, tasks, path following), and on
what a test can see happen (a message arrived, a row stored, a frame taken).

A test waits as long as the work advances and fails when it has not advanced for a stated
time, never at a fixed total deadline: a busy machine slows a run down, it does not stop it,
and a total deadline fails a run that was advancing (a network calibration still "running"
after 180 s on a busy machine, while its progress moved). What counts as advancing
is what the work reports (its status, stage and fraction), never a clock of the test's own.
A test never sleeps for something to happen: it waits until it has (`wait_until`), while what
leads to it moves (frames taken, rows stored), or, when nothing shows that, for a stated time.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Hashable
from typing import Any, TypeVar

T = TypeVar("T")

UNFINISHED = ("queued", "running")


class Stalled(AssertionError):
    """The work reported the same progress for longer than the test allows."""


def wait_while_advancing(
    read: Callable[[], T],
    *,
    done: Callable[[T], bool],
    progress: Callable[[T], Hashable],
    stalled_after_s: float,
    poll_s: float = 0.1,
    what: str = "the work",
) -> T:
    """Return read()'s value once `done` holds for it; raise Stalled when `progress` of the
    values read has not changed for `stalled_after_s` seconds (polling every `poll_s`)."""
    last: Hashable = None
    since = time.monotonic()
    started = since
    while True:
        value = read()
        if done(value):
            return value
        mark = progress(value)
        now = time.monotonic()
        if mark != last:
            last, since = mark, now
        elif now - since > stalled_after_s:
            raise Stalled(
                f"{what} reported no progress for {stalled_after_s:g} s "
                f"(after {now - started:.0f} s in all), stuck at {mark!r}: {value!r}"
            )
        time.sleep(poll_s)


def wait_until(
    condition: Callable[[], T],
    *,
    what: str,
    stalled_after_s: float,
    progress: Callable[[], Hashable] | None = None,
    poll_s: float = 0.1,
) -> T:
    """Return condition()'s value once it is true (a value that is not false, 0, None or
    empty); raise Stalled when it has not become so and `progress()` (when given: what moves
    while the work goes on, a count of frames or rows) has not changed for `stalled_after_s`
    seconds (polling every `poll_s`). Without `progress` nothing is seen to advance: the
    condition must hold within `stalled_after_s` seconds."""
    return wait_while_advancing(
        condition,
        done=bool,
        progress=(lambda _: progress()) if progress is not None else (lambda _: None),
        stalled_after_s=stalled_after_s,
        poll_s=poll_s,
        what=what,
    )


def wait_until_unchanged(
    read: Callable[[], T], *, what: str, interval_s: float, stalled_after_s: float
) -> T:
    """Return read()'s value once two reads `interval_s` apart give the same (what it reads has
    stopped moving: a paused clock, a stream no longer read); raise Stalled when it is still
    moving after `stalled_after_s` seconds."""
    reads: list[T] = []

    def unchanged() -> bool:
        reads.append(read())
        return len(reads) > 1 and reads[-1] == reads[-2]

    wait_until(
        unchanged, what=f"{what} standing still", stalled_after_s=stalled_after_s, poll_s=interval_s
    )
    return reads[-1]


def run_progress(run: dict[str, Any]) -> Hashable:
    """Return what moves while a calibration run advances: its status, its attempt and the
    stage and fraction it reported."""
    reported = run.get("progress") or {}
    return run["status"], run.get("attempts"), reported.get("stage"), reported.get("fraction")


def wait_for_run(
    read: Callable[[], dict[str, Any]], *, stalled_after_s: float, poll_s: float = 0.1
) -> dict[str, Any]:
    """Return the calibration run `read` returns (its JSON) once it is no longer queued or
    running; raise Stalled when its progress stays the same for `stalled_after_s` seconds."""
    return _wait_finished(read, run_progress, stalled_after_s, poll_s, "the calibration run")


def task_progress(task: dict[str, Any]) -> Hashable:
    """Return what moves while a task (or a path's following) advances: its status, phase
    (when it has one) and the share done."""
    return task["status"], task.get("phase"), task.get("progress")


def wait_for_task(
    read: Callable[[], dict[str, Any]], *, stalled_after_s: float, poll_s: float = 0.2
) -> dict[str, Any]:
    """Return the task `read` returns once it is no longer queued or running; raise Stalled
    when its phase and progress stay the same for `stalled_after_s` seconds."""
    return _wait_finished(read, task_progress, stalled_after_s, poll_s, "the task")


def _wait_finished(
    read: Callable[[], dict[str, Any]],
    progress: Callable[[dict[str, Any]], Hashable],
    stalled_after_s: float,
    poll_s: float,
    what: str,
) -> dict[str, Any]:
    """Return read()'s work once it is no longer queued or running (wait_while_advancing)."""
    return wait_while_advancing(
        read,
        done=lambda work: work["status"] not in UNFINISHED,
        progress=progress,
        stalled_after_s=stalled_after_s,
        poll_s=poll_s,
        what=what,
    )
