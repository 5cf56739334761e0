"""Timing helpers shared by the benchmarks: best-of-N wall time and a table with ratios."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence


def best_of(fn: Callable[[], object], repeats: int = 20, number: int = 1) -> float:
    """Return the smallest wall time of one call of fn, in seconds, over `repeats` rounds of
    `number` calls each (time.perf_counter). The minimum is the least disturbed by other load."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        best = min(best, (time.perf_counter() - t0) / number)
    return best


def print_table(
    title: str,
    rows: Sequence[tuple[str, float, dict[str, str]]],
    anchor: str,
) -> None:
    """Print rows (name, seconds, extra columns) with each time's ratio to the `anchor` row's,
    measured in the same run."""
    ref = {name: t for name, t, _ in rows}[anchor]
    extra_keys: list[str] = []
    for _, _, extra in rows:
        extra_keys += [k for k in extra if k not in extra_keys]
    width = max(len(name) for name, _, _ in rows)
    head = f"{'method':<{width}}  {'time':>10}  {'ratio':>7}" + "".join(
        f"  {k:>14}" for k in extra_keys
    )
    print(title)
    print(head)
    print("-" * len(head))
    for name, t, extra in rows:
        line = f"{name:<{width}}  {_fmt_time(t):>10}  {t / ref:>6.2f}x"
        line += "".join(f"  {extra.get(k, ''):>14}" for k in extra_keys)
        print(line)
    print(f"(ratio = time / time of '{anchor}')")


def _fmt_time(t: float) -> str:
    if t < 1e-3:
        return f"{t * 1e6:.0f} us"
    if t < 1.0:
        return f"{t * 1e3:.2f} ms"
    return f"{t:.2f} s"
