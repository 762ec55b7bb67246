"""``globloc record``: record every output topic of the design into a rosbag2 MCAP bag."""

from __future__ import annotations

import signal
import sys
from dataclasses import dataclass, field
from pathlib import Path

from rover_bringup.errors import GloblocError
from rover_bringup.msgtypes import message_classes
from rover_bringup.recording import OutputBag
from rover_bringup.topics import OUTPUT_TOPICS


@dataclass
class RecordOptions:
    """What ``globloc record`` does.

    Attributes:
        out: Bag directory to create.
        ros_args: Arguments for rclpy after ``--ros-args`` (e.g. ``-p use_sim_time:=true``).
    """

    out: Path
    ros_args: list[str] = field(default_factory=list)


def record(options: RecordOptions) -> int:
    """Record until SIGINT/SIGTERM, then close the bag (metadata.yaml is written then).

    Returns:
        Exit status: 0 after a clean stop.

    Raises:
        GloblocError: A message type is not installed, or the bag directory cannot be
            created.
    """
    topics = dict(OUTPUT_TOPICS)
    message_classes({t: c.msgtype for t, c in topics.items()})
    if options.out.exists():
        raise GloblocError(f'output bag {options.out} exists already')

    from roi_network.spin import spin_until_shutdown
    from rover_bringup.recorder_node import OutputRecorder
    from rover_bringup.ros import ros_args, ros_session

    out = OutputBag(options.out)
    try:
        with ros_session(ros_args('globloc_record', options.ros_args)):
            recorder = OutputRecorder(out, topics)
            try:
                spin_until_shutdown(recorder)
            finally:
                recorder.destroy_node()
    except KeyboardInterrupt:
        pass
    finally:
        # A second signal (Ctrl-C reaches the recorder, then globloc run's SIGTERM) must
        # not cut the bag's summary and metadata short: closing is quick, let it finish.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        out.close()
        # A plain print: after SIGTERM the context is gone and the ROS logger would complain
        # that it cannot publish to /rosout.
        counts = ', '.join(f'{t} {n}' for t, n in sorted(out.counts.items()))
        print(f'globloc record: stopped; recorded {counts or "nothing"} to {options.out}',
              file=sys.stderr, flush=True)
    return 0
