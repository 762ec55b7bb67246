"""``globloc run``: the node graph on a bag, as ``ros2 launch`` + ``ros2 bag play/record`` would.

Sequence: check the bag and the graph; start the recorder and every node (one process each,
``use_sim_time``); play the bag once all of them subscribed to /clock; let the graph drain;
stop nodes, then the recorder, with SIGTERM; write ``run.yaml`` with the run's status:
``ok`` (exit 0), ``degraded`` (exit 3: a node never started, exited, was restarted, or
published nothing on a topic it must publish; ``health``), ``failed`` (exit 1: a crash, a
playback failure) or ``interrupted`` (exit 130: SIGINT or SIGTERM; nothing is restarted).
Steps (docs/bringup.md, Method): 1 check, 2 write, 3 start, 4 play, 5 drain and stop,
6 export. Output layout::

    <out>/<bag>/<run>/
        outputs/metadata.yaml, outputs/outputs.mcap   rosbag2 bag of every output topic
        logs/<node>.log, logs/globloc_player.log, logs/globloc_recorder.log
        params.yaml                                   params file given to the nodes
        run.yaml                                      what ran, exit codes, message counts,
                                                      status and why
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from rover_bringup.bag import Bag, BagLocation, locate_bag
from rover_bringup.errors import GloblocError, say
from rover_bringup.gn_check import check_gn
from rover_bringup.graph import (
    Availability,
    Resolved,
    load_graph,
    load_params,
    node_command,
    resolve,
    substitute,
)
from rover_bringup.health import NodeRun, degraded_reasons, read_statuses
from rover_bringup.launcher import ManagedProcess, start, stop, tail
from rover_bringup.msgtypes import playable_classes
from rover_bringup.recording import count_messages
from rover_bringup.respawn import Respawner
from rover_bringup.run_outputs import export_outputs
from rover_bringup.share import config_file
from rover_bringup.topics import OUTPUT_TOPICS, TF_STATIC, sensor_problems
from rover_bringup.urdf import JOINT_STATES

#: Packages whose nodes read the bag's stereo pairs, CameraInfo and IMU.
SENSOR_READERS = ('rover_vo', 'roi_detector')

PLAYER = 'globloc_player'
RECORDER = 'globloc_recorder'
OUTPUTS = 'outputs'
#: Upper bound of the wait for the nodes to subscribe to /clock before playing (s).
STARTUP_TIMEOUT_S = 30.0
#: Seconds a process gets after SIGTERM before SIGKILL.
STOP_TIMEOUT_S = 10.0
#: Lines of a crashed node's log shown in the error.
TAIL_LINES = 20
_POLL_S = 0.1
#: After an interrupt, how long the children get to finish on the same signal (Ctrl-C
#: reaches the whole process group) before SIGTERM, seconds; the wait ends as soon as they
#: all exited. A node done with its own shutdown has its default handlers back, and a
#: SIGTERM then kills it (exit -15, its work done): on the demo bag at a load of 13 on 2
#: cores, the nodes took 3.2 to 5.6 s to exit on a SIGINT to the group.
INTERRUPT_GRACE_S = 5.0
#: Exit status of a run that failed: a node crashed after its last restart, playback failed.
EXIT_FAILED = 1
#: Exit status of a run that ended but is degraded (``health.degraded_reasons``).
EXIT_DEGRADED = 3
#: Exit status of an interrupted run (SIGINT or SIGTERM), as a shell reports SIGINT.
EXIT_INTERRUPTED = 130


@dataclass
class RunOptions:
    """What ``globloc run`` does; defaults match the CLI's.

    Attributes:
        bag: Bag directory.
        params: Params file (None: the package's config/globloc.yaml).
        graph: Graph file (None: the package's config/graph.yaml).
        rate: Playback rate factor (0: as fast as possible).
        out: Output root; the run goes to ``out/<bag>/<run_id>/``.
        run_id: Run directory name (None: local time stamp).
        drain_s: Seconds the graph keeps running after the bag ends.
        settle_s: Pause between the last node subscribing and the first message (s; see
            docs/bringup.md, "Discovery": Fast DDS sometimes misses the initial announcements
            between two processes and pairs them only at its next periodic one, 3 s later).
        strict: Fail on nodes that are not built instead of skipping them.
        max_restarts: Times a node that exits mid-run is restarted (0: never).
    """

    bag: Path
    params: Path | None = None
    graph: Path | None = None
    rate: float = 1.0
    out: Path = Path('out')
    run_id: str | None = None
    drain_s: float = 2.0
    settle_s: float = 3.5
    strict: bool = False
    max_restarts: int = 3


def _warn(message: str) -> None:
    say(f'globloc: warning: {message}')


def _info(message: str) -> None:
    say(f'globloc: {message}')


def _new_run_dir(out: Path, location: BagLocation, run_id: str | None) -> Path:
    base = out / location.name
    if run_id is not None:
        run_dir = base / run_id
        if run_dir.exists():
            raise GloblocError(f'run directory {run_dir} exists already (choose another --run-id)')
    else:
        stamp = datetime.now().strftime('%Y%m%d-%H%M%S')
        run_dir, n = base / stamp, 1
        while run_dir.exists():  # two runs in the same second
            n += 1
            run_dir = base / f'{stamp}-{n}'
    try:
        run_dir.mkdir(parents=True)
        (run_dir / 'logs').mkdir()
    except OSError as exc:
        raise GloblocError(f'cannot create run directory {run_dir}: {exc}') from None
    return run_dir


@dataclass(frozen=True)
class _Plan:
    """Everything checked before any process starts."""

    location: BagLocation
    nodes: list[Resolved]
    params: dict[str, Any]
    graph_path: Path
    params_path: Path

    @property
    def ready(self) -> list[Resolved]:
        return [r for r in self.nodes if r.availability is Availability.READY]


def _prepare(options: RunOptions) -> _Plan:
    """Every check that needs no process: bag, types, graph, params, executables."""
    location = locate_bag(options.bag)
    with Bag(location) as bag:
        bag_topics = {t.name: t.msgtype for t in bag.topics.values()}
        # Topics of types this install lacks (a field bag's /tf) are not played: the
        # player says which; the rest must be loadable.
        playable_classes(bag_topics, False, lambda _message: None)
    graph_path = options.graph or config_file('graph.yaml')
    params_path = options.params or config_file('globloc.yaml')
    nodes = load_graph(graph_path)
    params = load_params(params_path)
    if reserved := [n.name for n in nodes if n.name in (PLAYER, RECORDER)]:
        raise GloblocError(f'graph file {graph_path}: node name {reserved[0]} is reserved')
    # $RUN_DIR is not known yet: a command using it keeps the placeholder until start.
    variables = {'BAG_DIR': str(location.root.resolve()), 'PYTHON': sys.executable}
    prefixes = os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep)
    resolved = [resolve(n, variables, prefixes) for n in nodes]
    # A missing package or command is a mistake in the graph file: fatal. A package without
    # the executable, or a node whose input file is not prepared yet, is work in progress:
    # the graph runs with what exists, unless --strict.
    if missing := [r for r in resolved if r.availability is Availability.MISSING]:
        raise GloblocError(missing[0].reason)
    not_built = [r for r in resolved
                 if r.availability in (Availability.NOT_BUILT, Availability.NO_INPUT)]
    if not_built and options.strict:
        raise GloblocError(not_built[0].reason.replace(': skipped', ' (--strict)'))
    for r in not_built:
        _warn(r.reason)
    # The sensor readers in the graph, told what in the bag they cannot read.
    if readers := sorted({r.spec.name for r in resolved if r.spec.package in SENSOR_READERS}):
        for problem in sensor_problems(bag_topics, str(location.rosbag)):
            _warn(f'{problem} ({", ".join(readers)} will publish nothing)')
        _check_stereo_sync(location, params,
                           [(r.spec.name, r.spec.executable) for r in resolved])
        _check_mast(location, bag_topics, readers)
        if not (location.root / 'rover.yaml').is_file():
            hint = (f'write it from the bag\'s {TF_STATIC} with `globloc rover-yaml '
                    f'{location.root}`' if TF_STATIC in bag_topics else 'write it by hand '
                    '(docs/bringup.md)')
            _warn(f'{location.root / "rover.yaml"} not found: {", ".join(readers)} read the '
                  f'rover\'s extrinsics from it; {hint}')
    return _Plan(location, resolved, params, graph_path, params_path)


def _check_mast(location: BagLocation, bag_topics: dict[str, str], readers: list[str]) -> None:
    """Warn when ``rover.yaml`` puts the cameras on a mast and the bag records no
    ``/joint_states`` (the detector then places no pair), or when its mast parameters do
    not load."""
    import yaml

    from roi_network.mast import MastError, MastKinematics
    from roi_network.params import node_parameters

    path = location.root / 'rover.yaml'
    if not path.is_file():
        return
    try:
        kin = MastKinematics.from_params(node_parameters(yaml.safe_load(path.read_text()),
                                                         'roi_detector'))
    except (MastError, yaml.YAMLError) as exc:
        raise GloblocError(f'{path}: {exc}') from None
    if kin is not None and JOINT_STATES not in bag_topics:
        _warn(f'{path} puts the cameras on a mast ({kin.pan_joint}, {kin.tilt_joint}) but '
              f'{location.rosbag} records no {JOINT_STATES}: {", ".join(readers)} cannot '
              'place a stereo pair without its joint angles')


#: The stereo readers' sync parameters (roi_network.images.StereoHalves), by executable.
SYNC_PARAMETERS = {'rover_vo': 'features.stereo_sync_tolerance_s',
                   'roi_detector': 'stereo_sync_tolerance_s'}


def _check_stereo_sync(location: BagLocation, params: dict[str, Any],
                       nodes: list[tuple[str, str | None]]) -> None:
    """Warn when the bag's left and right images are stamped further apart than a stereo
    reader's sync tolerance (``nodes``: name and executable of the graph's nodes): that
    node would pair none of them. The tolerance is read as the node will get it: from the
    params file, then the bag's ``rover.yaml`` (given to every node after it)."""
    from roi_network.images import SYNC_TOLERANCE_S
    from rover_bringup.extrinsics import stereo_stamp_offsets

    offsets = stereo_stamp_offsets(location.rosbag)
    if not offsets:
        return
    files = [params]
    if (rover := location.root / 'rover.yaml').is_file():
        # The nodes that read a broken rover.yaml name what is wrong with it.
        with contextlib.suppress(OSError, yaml.YAMLError):
            files.append(yaml.safe_load(rover.read_text()) or {})
    median = float(np.median(offsets))
    for node, executable in nodes:
        key = SYNC_PARAMETERS.get(executable or '')
        if key is None:
            continue
        tolerance = float(node_parameter(files, node, key, SYNC_TOLERANCE_S))
        if median > tolerance:
            _warn(f'{location.rosbag}: its left and right images are stamped '
                  f'{median * 1e3:.1f} ms apart (median of the first {len(offsets)}), beyond '
                  f'{node}\'s {key} ({tolerance * 1e3:g} ms): it will pair none of them; '
                  'set the parameter in the params file (--params)')


def node_parameter(files: list[Any], node: str, key: str, default: Any) -> Any:
    """The value of parameter ``key`` (dotted: ``features.stereo_sync_tolerance_s``) that
    node ``node`` gets from params files ``files`` (parsed, in the order given), as a ROS 2
    params file gives it (:func:`roi_network.params.node_parameters`: the key dotted or
    nested, under ``/**`` or the node's name with or without its slash, the node's own
    entry over the wildcard), a later file over an earlier one. ``default`` when no file
    sets it."""
    from roi_network.params import node_parameters

    value = default
    for doc in files:
        value = node_parameters(doc, node).get(key, value)
    return value


def _write_params(plan: _Plan, run_dir: Path, variables: dict[str, str]) -> list[Path]:
    """Write ``<run>/params.yaml``; return the params files every node gets, in order."""
    params = substitute(plan.params, variables)
    if (dtm := plan.location.root / 'dtm.tif').is_file():  # /global_pose z from the DTM
        node = params.setdefault('darces_matcher', {}).setdefault('ros__parameters', {})
        node.setdefault('dtm_path', str(dtm))  # a user's own value (even '') stays
    params_run = run_dir / 'params.yaml'
    params_run.write_text(
        f'# {plan.params_path} with $BAG_DIR/$RUN_DIR substituted (and dtm_path set to the '
        'bag\'s dtm.tif, if any), as given to every node\n'
        + yaml.safe_dump(params, sort_keys=False)
    )
    files = [params_run]
    if (rover := plan.location.root / 'rover.yaml').is_file():
        files.append(rover)
    return files


class _Interrupt:
    """The SIGINT/SIGTERM handler of ``globloc run``.

    Installed whatever the inherited disposition: a job a non-interactive shell starts in
    the background inherits SIGINT ignored, while the ROS children install their own
    handlers, so that a Ctrl-C to the process group used to stop the nodes and leave the run
    restarting them. Until the first process starts it raises ``KeyboardInterrupt`` (there
    is nothing to stop); after that it only records the signal, and the supervision loop,
    which looks every ``_POLL_S``, stops the graph itself: no half-started child, no
    restart, the outputs closed. A second signal changes nothing: stopping is bounded
    (``STOP_TIMEOUT_S``), and cutting the recorder short would lose its bag.

    Attributes:
        signum: The first signal received, None before.
        raising: Raise ``KeyboardInterrupt`` on it (before anything started).
        event: Set on the first signal (mutes the player's echo at once).
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.signum: int | None = None
        self.raising = True
        self.event = threading.Event()
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> _Interrupt:
        if threading.current_thread() is threading.main_thread():
            self._previous = {sig: signal.signal(sig, self._handle) for sig in self.SIGNALS}
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)

    def _handle(self, signum: int, _frame: object) -> None:
        if self.signum is not None:
            return
        self.signum = signum
        self.event.set()
        if self.raising:
            raise KeyboardInterrupt

    def __call__(self) -> bool:
        """Whether a signal came."""
        return self.signum is not None

    @property
    def name(self) -> str:
        """``SIGINT`` or ``SIGTERM``."""
        return signal.Signals(self.signum).name if self.signum is not None else ''


def _supervise(
    options: RunOptions, plan: _Plan, run_dir: Path, params_files: list[Path],
    variables: dict[str, str], processes: dict[str, ManagedProcess], errors: list[str],
    respawn: Respawner, interrupt: _Interrupt,
) -> None:
    """Start recorder, nodes and player (filling ``processes``); return when the run is over.

    Over means: the bag was played and the drain time passed, a node crashed (as a
    required node does under ``ros2 launch``, a crash ends the run: the outputs of a graph
    with a dead node are not worth waiting for, and a node that dies at start-up would
    otherwise keep the player waiting for its /clock subscription), or an interrupt came
    (then nothing more is started or restarted).
    """
    logs = run_dir / 'logs'
    python = [sys.executable, '-m', 'rover_bringup.cli']
    # 3. Start the recorder, then every node.
    if interrupt():
        return
    processes[RECORDER] = start(
        RECORDER,
        [*python, 'record', str(run_dir / OUTPUTS), '--ros-args', '-p', 'use_sim_time:=true'],
        logs,
    )
    for r in plan.ready:
        if interrupt():
            return
        argv = [substitute(a, variables) for a in node_command(r, params_files)]
        processes[r.spec.name] = start(r.spec.name, argv, logs)
    watched = list(processes.values())
    if interrupt():
        return
    # 4. Play the bag once every process subscribed to /clock.
    player = processes[PLAYER] = start(
        PLAYER,
        [
            *python, 'play', str(plan.location.rosbag), '--rate', str(options.rate),
            # Graph nodes subscribe to what they need, not to every bag topic (nobody reads
            # the ground truth): wait for each node's /clock subscription instead.
            '--wait-topics', '--wait-for', str(len(watched)),
            '--wait-subscribers', str(STARTUP_TIMEOUT_S),
            '--settle', str(options.settle_s),
        ],
        logs,
        echo=True,
        muted=interrupt.event,
    )
    reported: set[str] = set()
    crash = _watch(watched, reported, lambda: player.returncode is not None, respawn,
                   interrupt)
    if interrupt():
        return
    if crash is None:
        if player.returncode != 0:
            errors.append(f'player exited with status {player.returncode} '
                          f'(log: {player.log_path})')
        # 5. Drain (stopping: run).
        end = time.monotonic() + options.drain_s
        crash = _watch(watched, reported, lambda: time.monotonic() >= end, respawn, interrupt)
    if crash is not None and not interrupt():
        _warn(f'{crash.name} crashed: stopping the run')


def _stop_all(plan: _Plan, processes: dict[str, ManagedProcess], respawn: Respawner,
              interrupt: _Interrupt) -> list[ManagedProcess]:
    """Stop every process; return the nodes' (graph order). Nodes first, so that the
    recorder still gets what they publish while stopping; after an interrupt every exit
    counts as the stop it is, the children get ``INTERRUPT_GRACE_S`` to finish on the
    signal if it reached them too, then the player goes first (no more input)."""
    nodes = [processes[r.spec.name] for r in plan.ready if r.spec.name in processes]
    tools = [processes[name] for name in (PLAYER, RECORDER) if name in processes]
    if interrupt():
        respawn.stopped = True
        for proc in processes.values():
            proc.stop_requested = True
        end = time.monotonic() + INTERRUPT_GRACE_S
        while time.monotonic() < end and any(p.returncode is None
                                             for p in processes.values()):
            time.sleep(_POLL_S)
        stop([p for p in tools if p.name == PLAYER], STOP_TIMEOUT_S)
    stop(nodes, STOP_TIMEOUT_S)
    stop(tools, STOP_TIMEOUT_S)
    if interrupt():  # it came while stopping: exits from it are no crash either
        for proc in processes.values():
            proc.stop_requested = True
    return nodes


def run(options: RunOptions) -> int:
    """Run the graph on a bag; see the module docstring.

    Returns:
        ``EXIT_DEGRADED`` (3) when a node never started, exited or was restarted, or
        published nothing on a topic it must (each named in one line, ``health``);
        ``EXIT_FAILED`` (1) when a node crashed (the error names it and shows its log tail)
        or playback failed; ``EXIT_INTERRUPTED`` (130) after SIGINT or SIGTERM; 0
        otherwise.

    Raises:
        GloblocError: Bad bag, graph or params file, or a missing executable (before anything
            is started).
    """
    with _Interrupt() as interrupt:
        try:
            # 1. Check everything that needs no process.
            bag_root = locate_bag(options.bag).root
            prepare_gn_if_missing(bag_root)
            check_gn(bag_root, _warn)
            plan = _prepare(options)
            interrupt.raising = False
        except KeyboardInterrupt:
            say(f'globloc: interrupted by {interrupt.name or "SIGINT"} before the graph '
                'started: nothing was run')
            return EXIT_INTERRUPTED
        return _run(options, plan, interrupt)


def _run(options: RunOptions, plan: _Plan, interrupt: _Interrupt) -> int:
    """Steps 2-6 of ``run``, the signals recorded by ``interrupt``."""
    run_dir = _new_run_dir(options.out, plan.location, options.run_id)
    variables = {
        'BAG_DIR': str(plan.location.root.resolve()),
        'RUN_DIR': str(run_dir.resolve()),
        'PYTHON': sys.executable,
    }
    # 2. Write <run>/params.yaml.
    params_files = _write_params(plan, run_dir, variables)
    started = datetime.now().isoformat(timespec='seconds')
    _info(f'run {run_dir}: {len(plan.ready)} of {len(plan.nodes)} nodes, '
          f'bag {plan.location.rosbag}')

    processes: dict[str, ManagedProcess] = {}
    errors: list[str] = []
    respawn = Respawner(options.max_restarts, run_dir / 'logs', processes,
                        {r.spec.name for r in plan.ready})
    try:
        # 3.-5. Start, play and drain (_supervise).
        _supervise(options, plan, run_dir, params_files, variables, processes, errors,
                   respawn, interrupt)
    finally:
        # 5. Stop.
        nodes = _stop_all(plan, processes, respawn, interrupt)

    if interrupt():
        errors.clear()  # the player's status, say: the interrupt's doing
    for proc in [*nodes, processes.get(RECORDER)]:
        if proc is not None and proc.crashed:
            what = 'the recorder' if proc.name == RECORDER else f'node {proc.name}'
            errors.append(
                f'{what} crashed (exit status {proc.returncode}); last lines of '
                f'{proc.log_path}:\n{tail(proc.log_path, TAIL_LINES).rstrip()}'
            )
    # 6. Export the outputs bag, judge the run and write run.yaml.
    unreadable = ''
    try:
        counts = count_messages(run_dir / OUTPUTS)
        statuses = read_statuses(run_dir / OUTPUTS)
    except GloblocError as exc:
        counts, statuses, unreadable = {}, {}, str(exc)
        errors.append(unreadable)
    degraded = [] if interrupt() else degraded_reasons(
        [_node_run(r, processes.get(r.spec.name), respawn) for r in plan.nodes],
        counts, statuses)
    if interrupt():
        status, code = 'interrupted', EXIT_INTERRUPTED
    elif errors:
        status, code = 'failed', EXIT_FAILED
    elif degraded:
        status, code = 'degraded', EXIT_DEGRADED
    else:
        status, code = 'ok', 0
    report = {
        'command': ['globloc', *sys.argv[1:]],  # this process's command line
        'bag': {'dir': str(plan.location.root), 'rosbag': str(plan.location.rosbag)},
        'run_dir': str(run_dir),
        'rate': options.rate,
        'graph_file': str(plan.graph_path),
        'params_file': str(plan.params_path),
        'params_files_used': [str(p) for p in params_files],
        'started': started,
        'finished': datetime.now().isoformat(timespec='seconds'),
        'nodes': [_node_entry(r, processes.get(r.spec.name), run_dir, counts)
                  | _restarts(respawn, r.spec.name) for r in plan.nodes],
        'tools': {name: _proc_entry(processes[name], run_dir)
                  for name in (PLAYER, RECORDER) if name in processes},
        'outputs': {
            'bag': str(run_dir / OUTPUTS),
            'messages': {t: counts.get(t, 0) for t in OUTPUT_TOPICS}
            | {t: n for t, n in counts.items() if t not in OUTPUT_TOPICS},
        },
        'status': status,
        'exit_code': code,
        **({'interrupted_by': interrupt.name} if interrupt() else {}),
        'degraded': degraded,
        'errors': errors,
    }
    report['outputs']['files'] = _export(run_dir, counts)
    (run_dir / 'run.yaml').write_text(yaml.safe_dump(report, sort_keys=False))
    recorded = ', '.join(f'{t} {n}' for t, n in counts.items() if n) or 'nothing'
    if interrupt():
        kept = (f'the outputs bag is unreadable: {unreadable}' if unreadable
                else f'recorded {recorded} -> {run_dir / OUTPUTS}')
        _info(f'interrupted by {interrupt.name}: graph stopped, nothing restarted; {kept}')
        return code
    _info(f'recorded {recorded} -> {run_dir / OUTPUTS}')
    for error in errors:
        say(f'globloc: error: {error}')
    for reason in degraded:
        say(f'globloc: degraded: {reason}')
    _info(f'status: {status}' + (f' (exit status {code}; {run_dir / "run.yaml"})'
                                 if code else ''))
    return code


def _node_run(r: Resolved, proc: ManagedProcess | None, respawn: Respawner) -> NodeRun:
    """A node as ``health`` judges it."""
    outputs = r.spec.expected_outputs
    if r.availability is Availability.NO_INPUT:
        return NodeRun(r.spec.name)  # no input for it in this bag (a GN): not expected
    if r.availability is not Availability.READY:
        return NodeRun(r.spec.name, outputs, not_started=r.reason.removesuffix(': skipped'))
    if proc is None:
        return NodeRun(r.spec.name, outputs, not_started='the run stopped before it')
    early = (proc.returncode if proc.returncode is not None and not proc.stop_requested
             and not proc.crashed else None)
    return NodeRun(r.spec.name, outputs, restart_codes=tuple(respawn.exits.get(r.spec.name, ())),
                   exited_early=early)


def _export(run_dir: Path, counts: dict[str, int]) -> dict[str, int]:
    """global_pose.tum, vo.tum, ... from the outputs bag (run_outputs); {} if unreadable."""
    if not counts:
        return {}
    try:
        return export_outputs(run_dir)
    except (GloblocError, OSError) as exc:
        _warn(f'outputs not exported to TUM files: {exc}')
        return {}


def _restarts(respawn: Respawner, name: str) -> dict[str, Any]:
    codes = respawn.exits.get(name)
    return {'restarts': len(codes), 'restarted_after_exit_codes': codes} if codes else {}


def _watch(
    processes: list[ManagedProcess], reported: set[str], until: Callable[[], bool],
    respawn: Callable[[ManagedProcess], ManagedProcess | None] | None = None,
    interrupted: Callable[[], bool] = lambda: False,
) -> ManagedProcess | None:
    """Poll until ``until()``, a crash or ``interrupted()``.

    Args:
        processes: Processes that should keep running (nodes, recorder); a restarted one
            is replaced in the list.
        reported: Names already reported as exited (updated).
        until: Condition that ends the watch.
        respawn: Called with a process that exited on its own; returns its restarted
            replacement, or None (then a crash ends the watch, a clean exit is reported).
        interrupted: True once the run is interrupted: the watch ends at once, restarting
            nothing (the children's exits are then the interrupt's).

    Returns:
        The first process found crashed (exited non-zero on its own) and not restarted,
        else None.
    """
    while not until() and not interrupted():
        for i, proc in enumerate(processes):
            if interrupted():
                return None
            if (proc.returncode is not None and not proc.stop_requested
                    and respawn is not None and (new := respawn(proc)) is not None):
                processes[i] = new
                continue
            if proc.crashed:
                return proc
            if proc.name not in reported and proc.returncode is not None:
                reported.add(proc.name)  # exited 0 on its own: odd, not fatal
                _warn(f'{proc.name} exited with status 0 while running (log: {proc.log_path})')
        time.sleep(_POLL_S)
    return None


def _proc_entry(proc: ManagedProcess, run_dir: Path) -> dict[str, Any]:
    return {
        'command': proc.argv,
        'exit_code': proc.returncode,
        'crashed': proc.crashed,
        'killed': proc.killed,
        'log': str(proc.log_path.relative_to(run_dir)),
    }


def _node_entry(r: Resolved, proc: ManagedProcess | None, run_dir: Path,
                counts: dict[str, int]) -> dict[str, Any]:
    spec = r.spec
    entry: dict[str, Any] = {'name': spec.name}
    if spec.command is not None:
        entry['command'] = list(spec.command)
    else:
        entry.update(package=spec.package, executable=spec.executable)
    if proc is None:
        entry['status'] = r.availability.value
        entry['reason'] = r.reason
        return entry
    entry['status'] = 'crashed' if proc.crashed else 'ran'
    entry.update(_proc_entry(proc, run_dir))
    if spec.expected_outputs:
        entry['published'] = {t: counts.get(t, 0) for t in spec.expected_outputs}
    return entry


# --- GN preparation hook (orbital_gn) ---------------------------------------------------------
# gn_server and darces_matcher need <bag>/gn.geojson; a bag from the simulator (or the field)
# comes with orbital.tif only. The GN is prepared once, offline, by the orbital_gn CLI (a
# separate process: rover_bringup does not import orbital_gn), and kept next to the bag.

def prepare_gn_if_missing(bag_root: Path) -> None:
    """Run ``orbital_gn prepare <bag>/orbital.tif --out <bag>/gn.geojson`` when the GN is
    missing. A no-op when the GN exists, when the bag has no orbital.tif, or when orbital_gn
    is not built; a failure is a warning (the nodes needing the GN are then skipped)."""
    import shutil
    import subprocess

    gn, ortho = bag_root / 'gn.geojson', bag_root / 'orbital.tif'
    if gn.exists() or not ortho.is_file():
        return
    exe = shutil.which('orbital_gn')
    for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        candidate = Path(prefix) / 'lib' / 'orbital_gn' / 'orbital_gn'
        if prefix and candidate.is_file():
            exe = str(candidate)
            break
    if exe is None:
        _warn(f'{gn} is missing and orbital_gn is not built: the GN is not prepared')
        return
    _info(f'preparing {gn} from {ortho} (orbital_gn prepare, once per bag)')
    result = subprocess.run([exe, 'prepare', str(ortho), '--out', str(gn), '--preview',
                             str(bag_root / 'gn.png'), '--no-progress'], check=False)
    if result.returncode != 0:
        _warn(f'orbital_gn prepare failed (exit status {result.returncode}): {gn} not prepared')
