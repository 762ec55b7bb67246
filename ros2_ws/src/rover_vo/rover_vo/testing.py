"""Helpers shared by the tests and the bench: the estimator over a list of messages."""

from __future__ import annotations

from typing import Any

from rover_vo.config import VoConfig
from rover_vo.estimator import VoEstimator, VoOutput


def run(messages: list[tuple[str, Any]], params: dict[str, Any],
        config: VoConfig | None = None) -> tuple[VoEstimator, list[VoOutput], list]:
    """Feed ``(topic, msg)`` in order; ``(estimator, outputs, [(level, text)] logged)``."""
    logs: list[tuple[int, str]] = []
    est = VoEstimator(config or VoConfig(), params, lambda lvl, text: logs.append((lvl, text)))
    outputs: list[VoOutput] = []
    for topic, msg in messages:
        outputs += est.feed(topic, msg)
    outputs += est.finish()
    return est, outputs, logs
