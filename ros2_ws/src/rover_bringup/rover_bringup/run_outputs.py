"""A run's recorded outputs as plain files for evaluation and other tools. No rclpy.

``globloc run`` (and ``globloc eval`` on a run directory that lacks them) turns
``<run>/outputs/`` (the rosbag2 bag of every output topic) into:

=========================  ================================================================
``global_pose.tum``        /global_pose, TUM (t x y z qx qy qz qw, base_link in ``map``)
``global_pose_cov.tsv``    its covariance per pose: t cov_xx cov_xy cov_yy cov_zz (m^2;
                           cov_zz 1e6: z not estimated, no DTM)
``vo.tum``                 /vo/odometry, TUM (base_link in ``odom``)
``vo_covariance.txt``      its pose covariance per pose: t and the 36 row-major entries
                           ([x y z rx ry rz]; m^2, rad^2), as ``rover_vo odometry`` writes
                           it (``roi_detector ln --odometry RUN/vo.tum`` reads it)
``alignment.tsv``          /global_alignment: t tx ty yaw (map -> odom; m, rad)
``matcher_events.tsv``     /matcher/status: t event reason ln_size inliers received
``local_network.csv``      the last /local_network (``odom`` frame): one ROI record a row
=========================  ================================================================

Times are the messages' header stamps (bag time, seconds). A /matcher/status carries
its LN's stamp, which can be well before the fix reached the graph (a detector behind
a fast replay), so ``matcher_events.tsv`` also has ``received``: when the recorder got
the message (its receive time, the bag's clock). Every file is written atomically (a
temporary file renamed), so a reader never sees half a file.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path

from roi_network.files import write_atomic
from roi_network.trajectory import (
    POSE_COVARIANCE_FILE,
    pose_covariance_header,
    pose_covariance_row,
    tum_row,
)
from rover_bringup.errors import GloblocError

OUTPUTS = 'outputs'
GLOBAL_POSE_TUM = 'global_pose.tum'
GLOBAL_POSE_COV = 'global_pose_cov.tsv'
VO_TUM = 'vo.tum'
VO_COV = POSE_COVARIANCE_FILE
ALIGNMENT = 'alignment.tsv'
EVENTS = 'matcher_events.tsv'
LOCAL_NETWORK = 'local_network.csv'
_TOPICS = ('/global_pose', '/vo/odometry', '/global_alignment', '/matcher/status',
           '/local_network')


def _stamp(header) -> float:
    return header.stamp.sec + 1e-9 * header.stamp.nanosec


def _tum_line(t: float, p, q) -> str:
    return tum_row(t, (p.x, p.y, p.z), (q.x, q.y, q.z, q.w)) + '\n'


def _lines(header: str, rows: Iterable[str]) -> str:
    return header + ''.join(rows)


def records_csv(records) -> str:
    """ROI records as CSV, a header of the ROI record's field names (roi_network)."""
    names = records.dtype.names
    rows = [','.join(repr(v.item()) for v in (r[n] for n in names)) for r in records]
    return ','.join(names) + '\n' + ''.join(row + '\n' for row in rows)


def read_records_csv(path: Path):
    """ROI records from :func:`records_csv`'s file.

    Raises:
        GloblocError: Unreadable, or its columns are not the ROI record's fields.
    """
    import numpy as np

    from roi_network.records import ROI_FIELDS, empty_records

    try:
        lines = [ln for ln in path.read_text().splitlines() if ln.strip()]
    except OSError as exc:
        raise GloblocError(f'cannot read {path}: {exc.strerror or exc}') from None
    if not lines or tuple(lines[0].split(',')) != ROI_FIELDS:
        raise GloblocError(f'{path}: header is not the ROI record fields {",".join(ROI_FIELDS)}')
    records = empty_records(len(lines) - 1)
    try:
        values = np.array([[float(v) for v in ln.split(',')] for ln in lines[1:]]).reshape(
            -1, len(ROI_FIELDS))
    except ValueError as exc:
        raise GloblocError(f'{path}: {exc}') from None
    for j, name in enumerate(ROI_FIELDS):
        records[name] = values[:, j]
    return records


RUN_YAML = 'run.yaml'


def run_status(run_dir: Path) -> dict:
    """The run's status as ``globloc run`` wrote it in ``run.yaml``, for ``globloc eval``.

    Returns:
        ``{'status': ok | degraded | failed | interrupted, 'exit_code': N, 'reasons':
        [one line each]}`` (the reasons: errors, then why degraded, or the interrupting
        signal); ``status`` is ``unknown`` when ``run.yaml`` is missing, unreadable or
        written before runs had a status.
    """
    import yaml

    try:
        doc = yaml.safe_load((run_dir / RUN_YAML).read_text())
    except (OSError, yaml.YAMLError) as exc:
        return {'status': 'unknown', 'exit_code': None,
                'reasons': [f'cannot read {run_dir / RUN_YAML}: {exc}']}
    if not isinstance(doc, dict) or doc.get('status') not in (
            'ok', 'degraded', 'failed', 'interrupted'):
        return {'status': 'unknown', 'exit_code': None,
                'reasons': [f'{run_dir / RUN_YAML} records no run status']}
    reasons = [str(e).splitlines()[0] for e in doc.get('errors') or []]
    reasons += [str(r) for r in doc.get('degraded') or []]
    if doc['status'] == 'interrupted':
        reasons.insert(0, f"interrupted by {doc.get('interrupted_by', 'a signal')}: the "
                       'outputs end where the run was stopped')
    return {'status': doc['status'], 'exit_code': doc.get('exit_code'), 'reasons': reasons}


def run_status_lines(status: dict | None) -> list[str]:
    """What ``globloc eval`` prints of :func:`run_status`: nothing for an ``ok`` run (or
    one whose run.yaml records no status: ``unknown`` stays in report.json), else ``run
    status: degraded`` and one line per reason."""
    if not status or status.get('status') in ('ok', 'unknown'):
        return []
    return [f"run status: {status['status']}",
            *(f'  {reason}' for reason in status.get('reasons', []))]


def export_outputs(run_dir: Path) -> dict[str, int]:
    """Write the files of the module docstring from ``<run_dir>/outputs/``.

    Args:
        run_dir: A run directory of ``globloc run``.

    Returns:
        Rows written per file name.

    Raises:
        GloblocError: The outputs bag is missing or unreadable (the message names it); a
            message that cannot be decoded is skipped and counted in ``'undecodable'``.
    """
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    bag = run_dir / OUTPUTS
    if not (bag / 'metadata.yaml').is_file():
        raise GloblocError(f'no outputs bag in {run_dir} (expected {bag}/metadata.yaml)')
    typestore = get_typestore(Stores.ROS2_JAZZY)
    poses, covs, vo, vo_cov, alignment, events = [], [], [], [], [], []
    last_ln = None
    undecodable = 0
    try:
        with Reader(bag) as reader:
            conns = [c for c in reader.connections if c.topic in _TOPICS]
            for conn, received_ns, raw in reader.messages(connections=conns):
                try:
                    msg = typestore.deserialize_cdr(raw, conn.msgtype)
                except Exception:  # a corrupt message must not lose the others
                    undecodable += 1
                    continue
                if conn.topic == '/global_pose':
                    t = _stamp(msg.header)
                    poses.append(_tum_line(t, msg.pose.pose.position, msg.pose.pose.orientation))
                    c = msg.pose.covariance
                    covs.append(f'{t:.9f} {c[0]:.9g} {c[1]:.9g} {c[7]:.9g} {c[14]:.9g}\n')
                elif conn.topic == '/vo/odometry':
                    vo.append(_tum_line(_stamp(msg.header), msg.pose.pose.position,
                                        msg.pose.pose.orientation))
                    vo_cov.append(pose_covariance_row(_stamp(msg.header),
                                                      msg.pose.covariance) + '\n')
                elif conn.topic == '/global_alignment':
                    r, tr = msg.transform.rotation, msg.transform.translation
                    yaw = 2.0 * math.atan2(r.z, r.w)
                    alignment.append(f'{_stamp(msg.header):.9f} {tr.x:.6f} {tr.y:.6f} '
                                     f'{yaw:.9f}\n')
                elif conn.topic == '/matcher/status':
                    for status in msg.status:
                        kv = {v.key: v.value for v in status.values}
                        events.append(
                            f'{_stamp(msg.header):.9f}\t{kv.get("event", "")}\t'
                            f'{kv.get("reason", "")}\t{kv.get("ln_size", "")}\t'
                            f'{kv.get("inliers", "")}\t{received_ns * 1e-9:.9f}\n')
                elif conn.topic == '/local_network':
                    last_ln = msg
    except GloblocError:
        raise
    except Exception as exc:  # rosbags ReaderError, truncated MCAP, ...
        raise GloblocError(f'cannot read outputs bag {bag}: {exc}') from None

    write_atomic(run_dir / GLOBAL_POSE_TUM,
                 _lines('# t x y z qx qy qz qw (/global_pose, map frame, base_link)\n', poses))
    write_atomic(run_dir / GLOBAL_POSE_COV,
                 _lines('# t cov_xx cov_xy cov_yy cov_zz (/global_pose covariance, m^2)\n',
                        covs))
    write_atomic(run_dir / VO_TUM,
                 _lines('# t x y z qx qy qz qw (/vo/odometry, odom frame, base_link)\n', vo))
    write_atomic(run_dir / VO_COV,
                 _lines(f'# {pose_covariance_header("/vo/odometry")}\n', vo_cov))
    write_atomic(run_dir / ALIGNMENT,
                 _lines('# t tx ty yaw (/global_alignment, map -> odom; m, rad)\n', alignment))
    write_atomic(run_dir / EVENTS,
                 _lines('# t\tevent\treason\tln_size\tinliers\treceived (/matcher/status; '
                        't: its LN\'s stamp, received: when the recorder got it)\n', events))
    written = {GLOBAL_POSE_TUM: len(poses), GLOBAL_POSE_COV: len(covs), VO_TUM: len(vo),
               VO_COV: len(vo_cov),
               ALIGNMENT: len(alignment), EVENTS: len(events), 'undecodable': undecodable}
    if last_ln is not None:
        try:
            from roi_network.pointcloud import from_pointcloud2

            records = from_pointcloud2(last_ln)
        except Exception:  # a malformed LN: the other files stand
            written['undecodable'] += 1
        else:
            write_atomic(run_dir / LOCAL_NETWORK, records_csv(records))
            written[LOCAL_NETWORK] = len(records)
    return written
