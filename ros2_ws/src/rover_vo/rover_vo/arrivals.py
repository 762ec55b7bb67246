"""How long a stereo pair waits for the rest of its input, in each input's own rate.

A pair is processed as soon as what it needs has come: its other image, the camera infos,
an IMU sample at or after its stamp (the gyro covers its interval) and, on a mast, a joint
state at or after it. Over DDS the topics arrive in any interleaving, and a sensor may be
dead: the pair then gives up waiting for an input once the other inputs' stamps have run
a few of that input's periods past the pair (:meth:`Arrivals.overdue`), the periods
measured from the stamps seen so far. Time is the sensors' stamps, never the wall clock,
so the offline CLI and the node decide alike.
"""

from __future__ import annotations

from collections import deque

import numpy as np

#: A pair gives up an IMU sample or a joint state after the other inputs' stamps have run
#: this many of that input's periods past it (5 periods: 0.1 s of a 50 Hz IMU, 0.5 s of
#: 10 Hz joint states).
WAIT_PERIODS = 5
#: A pair gives up its other half, or the camera infos, once its own camera has delivered
#: this many newer images.
WAIT_FRAMES = 2
#: Stamps kept per input for its period (the median interval).
HISTORY = 33


class Arrivals:
    """The newest stamps of each input stream (``imu``, ``joints``, ``left``, ``right``)
    and their typical interval.

    Args:
        default_periods: ``{stream: s}`` used while a stream has fewer than two stamps
            (rover.yaml's IMU rate, say).
    """

    def __init__(self, default_periods: dict[str, float] | None = None) -> None:
        self.default_periods = dict(default_periods or {})
        self._recent: dict[str, deque[float]] = {}

    def note(self, stream: str, t: float) -> None:
        """A message of ``stream`` stamped ``t`` (s) was taken; older stamps than its newest
        do not move it back."""
        recent = self._recent.setdefault(stream, deque(maxlen=HISTORY))
        if not recent or t > recent[-1]:
            recent.append(float(t))

    def newest(self, stream: str) -> float | None:
        """The newest stamp of ``stream`` (s), None before the first."""
        recent = self._recent.get(stream)
        return recent[-1] if recent else None

    def period(self, stream: str) -> float | None:
        """The median interval of the recent stamps of ``stream`` (s), else its default,
        else None."""
        recent = self._recent.get(stream)
        if recent is not None and len(recent) >= 2:
            return float(np.median(np.diff(np.asarray(recent))))
        return self.default_periods.get(stream)

    def clock(self, without: str) -> float | None:
        """The newest stamp of every stream but ``without`` (s): how far the rest of the
        input has come."""
        stamps = [r[-1] for s, r in self._recent.items() if s != without and r]
        return max(stamps) if stamps else None

    def newer(self, stream: str, t: float) -> int:
        """How many of the recent stamps of ``stream`` are after ``t``."""
        return sum(s > t for s in self._recent.get(stream, ()))

    def covers(self, stream: str, t: float) -> bool:
        """Whether ``stream`` has delivered a stamp at or after ``t``."""
        newest = self.newest(stream)
        return newest is not None and newest >= t

    def overdue(self, stream: str, t: float, periods: float = WAIT_PERIODS) -> bool:
        """Whether a pair at ``t`` has waited long enough for ``stream``: the other
        streams' stamps are more than ``periods`` of its period past ``t`` (a stream of no
        known period: any stamp past ``t``)."""
        clock = self.clock(stream)
        if clock is None:
            return False
        period = self.period(stream) or 0.0
        return clock > t + periods * period
