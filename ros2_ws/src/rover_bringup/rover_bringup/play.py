"""``globloc play``: replay a bag into the ROS graph with its recorded QoS and /clock.

Everything that can be wrong with the input (bag path, storage file, topic names, message
types) is checked before rclpy is even initialised, so bad input costs no DDS start-up and
leaves nothing behind.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from rover_bringup.bag import Bag, open_bag
from rover_bringup.errors import GloblocError
from rover_bringup.msgtypes import playable_classes
from rover_bringup.playback import NS_PER_S, PlaybackClock, Progress

if TYPE_CHECKING:
    from rover_bringup.player_node import BagPlayer

#: Exit status when playback is interrupted (SIGINT/SIGTERM), as a shell reports SIGINT.
EXIT_INTERRUPTED = 130

#: Wall seconds the middleware gets to tear down (node, context) once playback has ended;
#: then the process exits with playback's status anyway.
TEARDOWN_TIMEOUT_S = 15.0
#: Upper bound of the final wait for acknowledgements on reliable topics (wall seconds).
ACK_TIMEOUT_S = 10.0
#: Pause before exiting when best-effort topics have subscribers (no acknowledgements to
#: wait for), wall seconds.
LINGER_S = 0.5
#: /clock ticks per wall second while waiting between messages.
CLOCK_HZ = 100.0


def _warn(message: str) -> None:
    print(f'globloc: warning: {message}', file=sys.stderr, flush=True)


def _exit_if_teardown_hangs(status: int, timeout_s: float) -> threading.Timer:
    """Arm a watchdog: exit the process with ``status`` if teardown takes > ``timeout_s``.

    Playback's outcome is decided (every message sent, acknowledgements counted) before the
    node and the rclpy context are destroyed. A DDS participant's teardown can block
    indefinitely (Fast DDS, after the subscriber's process has ended); the bag was played,
    so the caller must get its exit status, not a hang.
    """

    def fire() -> None:
        print(
            f'globloc: play: middleware teardown still running after {timeout_s:g} s; '
            f'exiting with status {status}',
            file=sys.stderr, flush=True,
        )
        sys.stdout.flush()
        os._exit(status)

    timer = threading.Timer(timeout_s, fire)
    timer.daemon = True
    timer.start()
    return timer


@dataclass
class PlayOptions:
    """What ``globloc play`` does; defaults match the CLI's.

    Attributes:
        bag: Bag directory (rosbag2 dir, or ``bags/<name>/`` holding ``rosbag/``).
        rate: Playback rate factor (10: ten times faster); 0: as fast as possible.
        start_s: Bag seconds to skip at the start.
        topics: Topics to play; None: all.
        wait_topics: Topics that need a subscriber before the first message; None: every
            played topic; empty: none.
        wait_for: /clock subscribers to wait for (nodes started with use_sim_time).
        wait_timeout_s: Upper bound of the wait for subscribers (s; 0: do not wait).
        settle_s: Pause after the subscribers matched, so that subscriptions a node creates
            after its /clock one (a few ms later) are matched too (s).
        ros_args: Arguments for rclpy after ``--ros-args``.
    """

    bag: Path
    rate: float = 1.0
    start_s: float = 0.0
    topics: list[str] | None = None
    wait_topics: list[str] | None = None
    wait_for: int = 0
    wait_timeout_s: float = 5.0
    settle_s: float = 0.3
    ros_args: list[str] = field(default_factory=list)


#: Environment variables naming a Fast DDS XML profile (the second is Fast DDS 3's name).
PROFILE_VARIABLES = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE')


def use_player_profile() -> None:
    """Load the player's Fast DDS profile (config/fastdds_player.xml: a shared-memory
    segment that holds raw images) unless the environment names a profile already.
    Called before the player's DDS participant exists."""
    if not any(os.environ.get(name) for name in PROFILE_VARIABLES):
        from rover_bringup.share import config_file

        os.environ[PROFILE_VARIABLES[0]] = str(config_file('fastdds_player.xml'))


def play(options: PlayOptions) -> int:
    """Play a bag; see ``PlayOptions``.

    Args:
        options: What to play and how.

    Returns:
        Process exit status: 0 done, 1 reliable data left unacknowledged, 130 interrupted.

    Raises:
        GloblocError: Bad bag, topic or option (raised before anything is published), or a
            corrupt message met during playback.
    """
    if options.rate < 0:
        raise GloblocError(f'--rate must be >= 0, got {options.rate}')
    if options.start_s < 0:
        raise GloblocError(f'--start must be >= 0, got {options.start_s}')
    if options.wait_for < 0:
        raise GloblocError(f'--wait-for must be >= 0, got {options.wait_for}')
    with open_bag(options.bag) as bag:
        if not bag.message_count:
            raise GloblocError(f'bag {bag.location.rosbag} has no messages')
        selected = bag.select(options.topics)
        classes = playable_classes({t.name: t.msgtype for t in selected},
                                   bool(options.topics), _warn)
        selected = [t for t in selected if t.name in classes]
        names = [t.name for t in selected]
        wait_topics = names if options.wait_topics is None else sorted(set(options.wait_topics))
        if unknown := [t for t in wait_topics if t not in names]:
            raise GloblocError(f'--wait-topics: {unknown[0]} is not a played topic')
        start_ns = bag.start_ns + round(options.start_s * NS_PER_S)
        if start_ns > bag.end_ns:
            raise GloblocError(
                f'--start {options.start_s} is past the end of the bag '
                f'({(bag.end_ns - bag.start_ns) / NS_PER_S:.2f} s long)'
            )
        # rclpy is imported only now: bad input above fails fast, without starting DDS.
        use_player_profile()
        from rclpy.executors import ExternalShutdownException

        from rover_bringup.player_node import BagPlayer
        from rover_bringup.ros import ros_args, ros_session

        try:
            with ros_session(ros_args('globloc_play', options.ros_args)):
                player = BagPlayer(selected, classes)
                try:
                    status = _play(player, bag, options, names, wait_topics, start_ns)
                    # Armed for the rest of the process: destroy_node, rclpy shutdown and
                    # the interpreter's exit handlers; a daemon thread, so a normal exit
                    # does not wait for it.
                    _exit_if_teardown_hangs(status, TEARDOWN_TIMEOUT_S)
                    return status
                except RuntimeError:
                    # A signal shuts the context down between two rcl calls (publish, the
                    # acknowledgement wait, a subscription count): rclpy raises RCLError
                    # ("publisher's context is invalid", a RuntimeError) from whichever
                    # came next. That is the interruption it is, not a crash.
                    if player.context.ok():
                        raise
                    raise ExternalShutdownException() from None
                finally:
                    player.destroy_node()
        except (KeyboardInterrupt, ExternalShutdownException):
            print('globloc: play interrupted', file=sys.stderr, flush=True)
            return EXIT_INTERRUPTED


def _play(
    player: BagPlayer,
    bag: Bag,
    options: PlayOptions,
    names: list[str],
    wait_topics: list[str],
    start_ns: int,
) -> int:
    """Wait for subscribers, publish, wait for acknowledgements; returns the exit status."""
    logger = player.get_logger()
    if options.wait_timeout_s > 0 and (wait_topics or options.wait_for):
        missing = player.wait_for_subscribers(
            wait_topics, options.wait_for, options.wait_timeout_s
        )
        if missing:
            logger.warning(
                f'after {options.wait_timeout_s:g} s still no subscriber on: '
                f'{", ".join(missing)}; playing anyway'
            )
        time.sleep(options.settle_s)
    progress = Progress(start_ns, bag.end_ns)
    clock = PlaybackClock(start_ns, time.monotonic(), options.rate)
    t0 = time.monotonic()
    player.play(bag.messages(names, start_ns), clock, progress, 1.0 / CLOCK_HZ)
    unacked = player.wait_for_acks(ACK_TIMEOUT_S)
    if player.has_best_effort_subscribers():
        # Best effort has no acknowledgements: give the middleware a moment to hand the
        # last samples to the transport before the process (and its DDS participant) ends.
        time.sleep(LINGER_S)
    logger.info(
        f'done: {progress.line(bag.end_ns)} in {time.monotonic() - t0:.2f} s '
        f'(rate {options.rate:g})'
    )
    if player.corrupt:
        logger.warning(
            'corrupt messages skipped: '
            + ', '.join(f'{t} {n}' for t, n in sorted(player.corrupt.items()))
        )
    if unacked:
        logger.error(
            f'not acknowledged within {ACK_TIMEOUT_S:g} s on: {", ".join(unacked)}'
        )
        return 1
    return 0
