"""The ``globloc`` command: ``play`` a bag, ``run`` the node graph on a bag, ``record`` outputs,
``eval`` a run, ``rover-yaml`` a field bag's calibration file, ``camera-info`` the rectified
CameraInfo pair of a raw stereo calibration.

Only argument mapping lives here; each subcommand is a function taking an options object.
User errors (``GloblocError``) become one ``globloc: error: ...`` line on stderr and exit
status 1, never a traceback.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from rover_bringup.errors import GloblocError

PROG = 'globloc'


def _split_ros_args(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    # Everything after --ros-args belongs to rclpy (remappings, log levels...), as with
    # `ros2 run`; argparse must not see it.
    argv = list(argv)
    if '--ros-args' in argv:
        i = argv.index('--ros-args')
        return argv[:i], argv[i + 1 :]
    return argv, []


def _positive_float(text: str) -> float:
    value = float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f'must be >= 0, got {text}')
    return value


def _add_play(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        'play',
        help='replay a bag (MCAP or sqlite3) with its recorded QoS, and /clock',
        description='Replay a rosbag2 bag: stored CDR bytes, recorded QoS, /clock from bag '
        'time. Arguments after --ros-args go to rclpy.',
    )
    p.add_argument('bag', type=Path, metavar='BAG_DIR',
                   help='rosbag2 directory, or a bag directory bags/<name>/ holding rosbag/')
    p.add_argument('--rate', type=_positive_float, default=1.0,
                   help='rate factor: 10 plays ten times faster; 0 as fast as possible '
                   '(default: %(default)s)')
    p.add_argument('--start', type=_positive_float, default=0.0, metavar='S',
                   help='skip the first S seconds of the bag (default: %(default)s)')
    p.add_argument('--topics', nargs='+', metavar='T', help='play only these topics')
    p.add_argument('--wait-topics', nargs='*', metavar='T',
                   help='topics that need a subscriber before the first message (default: '
                   'every played topic; give the flag alone for none)')
    p.add_argument('--wait-for', type=int, default=0, metavar='N',
                   help='also wait for N subscribers on /clock, i.e. N nodes started with '
                   'use_sim_time (default: %(default)s)')
    p.add_argument('--wait-subscribers', type=_positive_float, default=5.0, metavar='SEC',
                   help='upper bound of the wait for subscribers; 0: do not wait '
                   '(default: %(default)s)')
    p.add_argument('--settle', type=_positive_float, default=0.3, metavar='SEC',
                   help='pause after the subscribers matched, before the first message '
                   '(default: %(default)s)')


def _add_run(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        'run',
        help='run the node graph on a bag and record its outputs',
        description='Start every node of the graph (one process each, use_sim_time), play '
        'the bag, record the output topics to out/<bag>/<run>/outputs/, stop the nodes.',
    )
    p.add_argument('bag', type=Path, metavar='BAG_DIR',
                   help='bag directory bags/<name>/ (or a rosbag2 directory)')
    p.add_argument('--params', type=Path, metavar='FILE',
                   help='ROS params file of all nodes (default: rover_bringup/config/'
                   'globloc.yaml)')
    p.add_argument('--graph', type=Path, metavar='FILE',
                   help='graph file listing the nodes (default: rover_bringup/config/'
                   'graph.yaml)')
    p.add_argument('--rate', type=_positive_float, default=1.0,
                   help='playback rate factor (default: %(default)s)')
    p.add_argument('--out', type=Path, default=Path('out'), metavar='DIR',
                   help='output root; the run goes to DIR/<bag>/<run>/ (default: %(default)s)')
    p.add_argument('--run-id', metavar='ID',
                   help='run directory name (default: local time, e.g. 20261122-031500)')
    p.add_argument('--drain', type=_positive_float, default=2.0, metavar='SEC',
                   help='seconds the graph keeps running after the bag ends '
                   '(default: %(default)s)')
    p.add_argument('--settle', type=_positive_float, default=3.5, metavar='SEC',
                   help='pause between the last node subscribing and the first message, so '
                   'that every pair of processes has discovered each other; Fast DDS can miss '
                   'the initial announcements and recover only at its next periodic one, 3 s '
                   'later (default: %(default)s)')
    p.add_argument('--strict', action='store_true',
                   help='fail when a node of the graph is not built, instead of skipping it')
    p.add_argument('--max-restarts', type=int, default=3, metavar='N',
                   help='restart a node that exits mid-run up to N times (0: a crash ends '
                   'the run at once) (default: %(default)s)')


def _add_record(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        'record',
        help='record the output topics to a rosbag2 MCAP bag (used by run)',
        description='Record every output topic of the pipeline (raw CDR, offered QoS) into a '
        'new rosbag2 directory with MCAP storage until SIGINT/SIGTERM. Arguments after '
        '--ros-args go to rclpy (run passes -p use_sim_time:=true).',
    )
    p.add_argument('out', type=Path, metavar='OUT_BAG_DIR', help='bag directory to create')


def _add_eval(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        'eval',
        help='judge a run against the bag\'s ground truth: report.json, report.md, plots',
        description='Evaluate out/<bag>/<run>/: /global_pose against BAG/truth/trajectory.tum '
        '(unaligned horizontal error, final error, RMSE after the first fix, distance before '
        'the first fix, false fixes, 3-sigma consistency). Writes report.json, report.md, '
        'route.png and error.png into the run directory.',
    )
    p.add_argument('run_dir', type=Path, metavar='RUN_DIR', help='run directory of globloc run')
    p.add_argument('--bag', type=Path, metavar='BAG_DIR',
                   help='bag directory holding truth/ (default: the one in RUN_DIR/run.yaml)')
    p.add_argument('--json', action='store_true', help='print report.json to stdout')
    p.add_argument('--no-plots', action='store_true', help='skip the plots')


def _add_salvage(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        'salvage',
        help='copy the complete chunks of a cut-short MCAP bag into a new bag',
        description='Read a rosbag2 MCAP file that has no summary or end marker (the '
        'recording was cut short) from its start, and copy every message of its complete '
        'chunks, with types and offered QoS, into a new rosbag2 directory.',
    )
    p.add_argument('bag', type=Path, metavar='BAG',
                   help='bag directory (bags/<name>/ or its rosbag/), or the .mcap file')
    p.add_argument('--out', type=Path, required=True, metavar='NEW_BAG_DIR',
                   help='rosbag2 directory to create')


def _add_rover_yaml(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        'rover-yaml',
        help="write a field bag's rover.yaml from the calibration the bag records",
        description="Write BAG_DIR/rover.yaml, the rover's extrinsics and sensor constants "
        'the nodes read (DESIGN.md), from what the bag records: /tf_static (composed along '
        "the tree from the base frame to each sensor's header.frame_id), the CameraInfo "
        "(intrinsics, baseline) and the IMU's stamps (rate). The IMU noise densities are "
        "rover_vo's defaults, flagged in the file. Every CameraInfo is checked: an unusable "
        'one (fx = 0, no baseline...) is skipped and named once; a topic with none usable, or '
        'left and right of different sizes, is refused. An existing file is not overwritten.',
    )
    p.add_argument('bag', type=Path, metavar='BAG_DIR',
                   help='bag directory (holding rosbag/) or a rosbag2 directory')
    p.add_argument('--out', type=Path, metavar='FILE',
                   help='file to write (default: rover.yaml in the bag directory)')
    p.add_argument('--force', action='store_true', help='overwrite an existing file')
    p.add_argument('--base-frame', default='base_link', metavar='FRAME',
                   help='the rover body frame (default: %(default)s)')
    for side in ('left', 'right', 'imu'):
        p.add_argument(f'--{side}-frame', metavar='FRAME',
                       help=f'the {side} sensor frame (default: the header.frame_id of its '
                       'messages)')


def _add_camera_info(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        'camera-info',
        help='the rectified stereo CameraInfo pair (K, D, R, P) of a raw stereo calibration',
        description='Compute the CameraInfo pair a raw-image stereo bag needs (K and D of '
        'the raw cameras, R into the rectified ones, the rectified P, the right one with '
        'P[3] = -fx * baseline) from two EuRoC-style sensor.yaml files (T_BS, resolution, '
        'intrinsics [fu, fv, cu, cv], distortion_model radial-tangential / radtan / '
        "plumb_bob, distortion_coefficients), with OpenCV's stereoRectify. Writes "
        'OUT_DIR/left.yaml and OUT_DIR/right.yaml in camera_calibration_parsers\' format, '
        'or prints both; says where the rectified cameras are in the body frame of T_BS '
        '(the pipeline takes the camera frames as the rectified cameras and ignores R).',
    )
    p.add_argument('left', type=Path, metavar='LEFT_SENSOR_YAML',
                   help="the left camera's sensor.yaml (EuRoC: cam0/sensor.yaml)")
    p.add_argument('right', type=Path, metavar='RIGHT_SENSOR_YAML',
                   help="the right camera's sensor.yaml (EuRoC: cam1/sensor.yaml)")
    p.add_argument('--out', type=Path, metavar='OUT_DIR',
                   help='write OUT_DIR/left.yaml and OUT_DIR/right.yaml (default: print both '
                   'to stdout)')
    p.add_argument('--alpha', type=float, default=0.0,
                   help='0: the rectified images hold valid pixels only; 1: every raw pixel, '
                   'with black borders (default: %(default)s)')
    p.add_argument('--force', action='store_true', help='overwrite existing files')


def build_parser() -> argparse.ArgumentParser:
    """The ``globloc`` argument parser."""
    parser = argparse.ArgumentParser(
        prog=PROG, description='Rover global localization: bag playback and node graph.'
    )
    sub = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')
    _add_play(sub)
    _add_run(sub)
    _add_record(sub)
    _add_eval(sub)
    _add_salvage(sub)
    _add_rover_yaml(sub)
    _add_camera_info(sub)
    return parser


def _dispatch(args: argparse.Namespace, ros: list[str]) -> int:
    if args.command == 'play':
        from rover_bringup.play import PlayOptions, play

        return play(
            PlayOptions(
                bag=args.bag,
                rate=args.rate,
                start_s=args.start,
                topics=args.topics,
                wait_topics=args.wait_topics,
                wait_for=args.wait_for,
                wait_timeout_s=args.wait_subscribers,
                settle_s=args.settle,
                ros_args=ros,
            )
        )
    if args.command == 'record':
        from rover_bringup.record import RecordOptions, record

        return record(RecordOptions(out=args.out, ros_args=ros))
    if args.command == 'salvage':
        from rover_bringup.salvage import salvage

        report = salvage(args.bag, args.out)
        topics = ', '.join(f'{t} {n}' for t, n in sorted(report.topics.items()))
        print(f'{PROG}: salvaged {report.messages} messages ({topics}) from {report.source} '
              f'into {report.out}; last at bag time {report.last_time_ns / 1e9:.3f} s'
              + (f'; reading stopped at: {report.stopped} (the incomplete rest is lost)'
                 if report.stopped else ''), file=sys.stderr)
        return 0
    if args.command == 'rover-yaml':
        from rover_bringup.extrinsics import write_rover_yaml

        frames = {side: getattr(args, f'{side}_frame') for side in ('left', 'right', 'imu')
                  if getattr(args, f'{side}_frame')}
        path, warnings = write_rover_yaml(args.bag, args.out, args.base_frame, frames,
                                          args.force)
        for warning in warnings:
            print(f'{PROG}: warning: {warning}', file=sys.stderr)
        print(f'{PROG}: wrote {path}', file=sys.stderr)
        return 0
    if args.command == 'camera-info':
        from rover_bringup.rectify import summary_lines, write_camera_info

        pair, written, text = write_camera_info(args.left, args.right, args.out, args.alpha,
                                                args.force)
        for line in summary_lines(pair):
            print(f'{PROG}: {line}', file=sys.stderr)
        if written:
            print(f'{PROG}: wrote {", ".join(str(p) for p in written)}', file=sys.stderr)
        else:
            print(text, end='')
        return 0
    if args.command == 'eval':
        from rover_bringup.evaluation import summary_lines
        from rover_bringup.report import REPORT_MD, EvalOptions, evaluate_run, report_json

        summary = evaluate_run(EvalOptions(run_dir=args.run_dir, bag=args.bag,
                                           plots=not args.no_plots))
        if args.json:
            print(report_json(summary), end='')
        else:
            for line in summary_lines(summary):
                print(line)
            print(f'report: {args.run_dir / REPORT_MD}', file=sys.stderr)
        return 0
    from rover_bringup.run import RunOptions, run

    return run(
        RunOptions(
            bag=args.bag,
            params=args.params,
            graph=args.graph,
            rate=args.rate,
            out=args.out,
            run_id=args.run_id,
            drain_s=args.drain,
            settle_s=args.settle,
            strict=args.strict,
            max_restarts=max(args.max_restarts, 0),
        )
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``globloc`` console script.

    Args:
        argv: Arguments without the program name (default: ``sys.argv[1:]``).

    Returns:
        Exit status.
    """
    own, ros = _split_ros_args(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(own)
    try:
        return _dispatch(args, ros)
    except GloblocError as exc:
        print(f'{PROG}: error: {exc}', file=sys.stderr, flush=True)
        return 1


if __name__ == '__main__':
    sys.exit(main())
