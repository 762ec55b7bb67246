"""Wall time per stage of a match, milliseconds (:attr:`MatchResult.timings_ms`)."""

from __future__ import annotations

import time


def elapsed_ms(t0: float) -> float:
    """Milliseconds since ``t0`` (a :func:`time.perf_counter` reading)."""
    return 1e3 * (time.perf_counter() - t0)


def add_stage(timings: dict[str, float], stage: str, t0: float) -> None:
    """Add the time since ``t0`` to ``stage`` (a stage may run once per round)."""
    timings[stage] = timings.get(stage, 0.0) + elapsed_ms(t0)


def with_total(t_start: float, timings: dict[str, float]) -> dict[str, float]:
    """``timings`` with ``"total"``, the time since ``t_start``."""
    timings["total"] = elapsed_ms(t_start)
    return timings
