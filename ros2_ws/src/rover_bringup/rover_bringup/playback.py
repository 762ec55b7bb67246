"""Playback timing: bag time <-> wall time at a rate factor, and progress lines. No rclpy.

Time stamps are integers in nanoseconds (bag time); wall times are ``time.monotonic()``
seconds, which never jump.
"""

from __future__ import annotations

from dataclasses import dataclass, field

NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class PlaybackClock:
    """Where bag time should be at a given wall time.

    Attributes:
        bag_start_ns: Bag time played at ``wall_start``.
        wall_start: Monotonic wall time (s) playback started.
        rate: Bag seconds per wall second (10 plays ten times faster); 0 or less: as fast as
            possible (no pacing).
    """

    bag_start_ns: int
    wall_start: float
    rate: float

    @property
    def paced(self) -> bool:
        """Whether messages are held back until their time comes."""
        return self.rate > 0

    def wall_time_of(self, bag_ns: int) -> float:
        """Monotonic wall time at which bag time ``bag_ns`` is due (now if unpaced)."""
        if not self.paced:
            return self.wall_start
        return self.wall_start + (bag_ns - self.bag_start_ns) / NS_PER_S / self.rate

    def bag_time_at(self, wall: float) -> int:
        """Bag time (ns) due at monotonic wall time ``wall`` (the start if unpaced)."""
        if not self.paced:
            return self.bag_start_ns
        return self.bag_start_ns + round((wall - self.wall_start) * self.rate * NS_PER_S)


@dataclass
class Progress:
    """Counts sent messages and says when a periodic progress line is due.

    Attributes:
        start_ns: First bag time played.
        end_ns: Last bag time to play.
        period_s: Wall seconds between progress lines.
        sent: Messages published so far (clock messages excluded).
    """

    start_ns: int
    end_ns: int
    period_s: float = 2.0
    sent: int = 0
    _next_report: float | None = field(default=None, repr=False)

    def fraction(self, bag_ns: int) -> float:
        """Share of the played time span done at bag time ``bag_ns`` (0..1)."""
        span = self.end_ns - self.start_ns
        if span <= 0:
            return 1.0
        return min(max((bag_ns - self.start_ns) / span, 0.0), 1.0)

    def line(self, bag_ns: int) -> str:
        """One-line status, e.g. ``bag time 3.20/10.00 s (32%), 420 msgs sent``."""
        return (
            f'bag time {(bag_ns - self.start_ns) / NS_PER_S:.2f}/'
            f'{(self.end_ns - self.start_ns) / NS_PER_S:.2f} s '
            f'({100 * self.fraction(bag_ns):.0f}%), {self.sent} msgs sent'
        )

    def due(self, wall: float) -> bool:
        """Whether a progress line is due at monotonic wall time ``wall`` (re-arms itself)."""
        if self._next_report is None:
            self._next_report = wall + self.period_s
            return False
        if wall < self._next_report:
            return False
        self._next_report = wall + self.period_s
        return True
