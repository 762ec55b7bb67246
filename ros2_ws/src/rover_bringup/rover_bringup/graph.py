"""The node graph of ``globloc run``: graph file, params file, executables. No rclpy.

Graph file (YAML)::

    nodes:
      - name: rover_vo          # ROS node name (also the params-file key and log name)
        package: rover_vo       # ament package ...
        executable: rover_vo    # ... and its console script: <prefix>/lib/<package>/<exe>
        requires: [$BAG_DIR/gn.geojson]   # optional: input files it cannot start without
      - name: my_test_node
        command: [$PYTHON, /path/to/node.py]   # or an explicit command line
        outputs: [/vo/odometry]   # optional: topics it must publish (DEFAULT_OUTPUTS)

Params file: the standard ROS 2 layout (``node_name: {ros__parameters: {...}}``, ``/**`` for
all nodes). String values may use ``$BAG_DIR`` (the bag's directory, holding ``rover.yaml``)
and ``$RUN_DIR`` (this run's output directory); ``$PYTHON`` also works in commands.
"""

from __future__ import annotations

import os
import shutil
import string
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

import yaml

from rover_bringup.errors import GloblocError

#: Keys a graph entry may have.
_NODE_KEYS = {'name', 'package', 'executable', 'command', 'requires', 'outputs'}

#: Topics each node of the project must publish at least once in a run (``globloc run``
#: calls the run degraded otherwise), by (package, executable). A graph entry's ``outputs``
#: replaces this; a node found in neither is not checked.
DEFAULT_OUTPUTS: dict[tuple[str, str], tuple[str, ...]] = {
    ('orbital_gn', 'gn_server'): ('/global_network',),
    ('rover_vo', 'rover_vo'): ('/vo/odometry',),
    ('roi_detector', 'roi_detector'): ('/rois/detections', '/rois/tracks'),
    ('roi_detector', 'ln_builder'): ('/local_network',),
    # It runs only with a GN (its graph entry requires one): then a run must localize.
    ('darces_matcher', 'darces_matcher'): ('/global_pose', '/matcher/status'),
}


@dataclass(frozen=True)
class NodeSpec:
    """One node of the graph: either ``package`` + ``executable`` or an explicit ``command``.

    Attributes:
        name: ROS node name (remapped with ``-r __node:=<name>``).
        package: ament package holding the executable.
        executable: Executable name in ``<prefix>/lib/<package>/``.
        command: Explicit command line (argv), used instead of package/executable.
        requires: Input files the node cannot start without (``$BAG_DIR`` substituted),
            e.g. the GN file that ``orbital_gn`` prepares offline.
        outputs: Topics the node must publish in a run (None: ``DEFAULT_OUTPUTS``).
    """

    name: str
    package: str | None = None
    executable: str | None = None
    command: tuple[str, ...] | None = None
    requires: tuple[str, ...] = ()
    outputs: tuple[str, ...] | None = None

    @property
    def expected_outputs(self) -> tuple[str, ...]:
        """The topics it must publish: its ``outputs``, else ``DEFAULT_OUTPUTS``, else ()."""
        if self.outputs is not None:
            return self.outputs
        return DEFAULT_OUTPUTS.get((self.package or '', self.executable or ''), ())

    def describe(self) -> str:
        """``node X (package P, executable E)`` or ``node X (command C)``."""
        if self.command is not None:
            return f'node {self.name} (command {" ".join(self.command)})'
        return f'node {self.name} (package {self.package}, executable {self.executable})'


def _load_yaml(path: Path, what: str) -> Any:
    try:
        return yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise GloblocError(f'{what} not found: {path}') from None
    except (OSError, yaml.YAMLError) as exc:
        reason = ' '.join(str(exc).split())
        raise GloblocError(f'cannot read {what} {path}: {reason}') from None


def load_graph(path: Path) -> list[NodeSpec]:
    """Read and validate a graph file.

    Args:
        path: Graph YAML file.

    Returns:
        The nodes, in file order (the start order).

    Raises:
        GloblocError: Unreadable file or an invalid entry (named).
    """
    doc = _load_yaml(path, 'graph file')
    entries = doc.get('nodes') if isinstance(doc, dict) else None
    if not isinstance(entries, list):
        raise GloblocError(f'graph file {path}: expected a top-level "nodes:" list')
    nodes: list[NodeSpec] = []
    for i, entry in enumerate(entries):
        where = f'graph file {path}, nodes[{i}]'
        if not isinstance(entry, dict) or not isinstance(entry.get('name'), str):
            raise GloblocError(f'{where}: expected a mapping with a "name"')
        if unknown := sorted(set(entry) - _NODE_KEYS):
            raise GloblocError(f'{where}: unknown key {unknown[0]!r}')
        requires = entry.get('requires', [])
        if not isinstance(requires, list) or not all(isinstance(r, str) for r in requires):
            raise GloblocError(f'{where}: "requires" must be a list of file paths')
        outputs = entry.get('outputs')
        if outputs is not None and (not isinstance(outputs, list) or not all(
                isinstance(t, str) and t.startswith('/') for t in outputs)):
            raise GloblocError(f'{where}: "outputs" must be a list of topic names (/...)')
        outputs = None if outputs is None else tuple(outputs)
        command = entry.get('command')
        if command is not None:
            if isinstance(command, str):
                command = command.split()
            if not command or not all(isinstance(c, str | int | float) for c in command):
                raise GloblocError(f'{where}: "command" must be a non-empty list of strings')
            nodes.append(NodeSpec(name=entry['name'], command=tuple(str(c) for c in command),
                                  requires=tuple(requires), outputs=outputs))
        elif isinstance(entry.get('package'), str) and isinstance(entry.get('executable'), str):
            nodes.append(
                NodeSpec(
                    name=entry['name'], package=entry['package'], executable=entry['executable'],
                    requires=tuple(requires), outputs=outputs,
                )
            )
        else:
            raise GloblocError(f'{where}: give either "command" or "package" and "executable"')
    names = [n.name for n in nodes]
    if dupes := sorted({n for n in names if names.count(n) > 1}):
        raise GloblocError(f'graph file {path}: node name {dupes[0]} is used twice')
    return nodes


def load_params(path: Path) -> dict[str, Any]:
    """Read a ROS 2 params file and check its layout (what rcl's parser would reject).

    Raises:
        GloblocError: Unreadable file or a node entry without ``ros__parameters``.
    """
    doc = _load_yaml(path, 'params file')
    if doc is None:
        return {}
    if not isinstance(doc, dict):
        raise GloblocError(f'params file {path}: expected a mapping of node names')
    for node, body in doc.items():
        if not isinstance(body, dict) or not isinstance(body.get('ros__parameters'), dict):
            raise GloblocError(
                f'params file {path}: {node} must be a mapping with a "ros__parameters" mapping'
            )
    return doc


def substitute(value: Any, variables: Mapping[str, str]) -> Any:
    """Replace ``$NAME`` / ``${NAME}`` in every string of a nested structure.

    Unknown variables are left as they are (a literal ``$`` in a value stays valid).
    """
    if isinstance(value, str):
        return string.Template(value).safe_substitute(variables)
    if isinstance(value, dict):
        return {k: substitute(v, variables) for k, v in value.items()}
    if isinstance(value, list):
        return [substitute(v, variables) for v in value]
    return value


class Availability(Enum):
    """Whether a node can be started."""

    READY = 'ready'
    NOT_BUILT = 'not built'  # its package exists but has no such executable (yet)
    NO_INPUT = 'no input'  # built, but an input file it requires does not exist (yet)
    MISSING = 'missing'  # no such package / command: a mistake in the graph file


@dataclass(frozen=True)
class Resolved:
    """A node with its command line, or the reason it has none.

    Attributes:
        spec: The graph entry.
        availability: Whether it can be started.
        argv: Command line without ROS arguments (empty unless READY).
        reason: One-line explanation when not READY.
    """

    spec: NodeSpec
    availability: Availability
    argv: tuple[str, ...] = ()
    reason: str = ''


def package_prefix(package: str, prefixes: Sequence[str]) -> Path | None:
    """Install prefix of an ament package (as ``ros2 run`` finds it), or None.

    Args:
        package: Package name.
        prefixes: AMENT_PREFIX_PATH entries, in priority order.
    """
    for prefix in prefixes:
        marker = Path(prefix) / 'share' / 'ament_index' / 'resource_index' / 'packages' / package
        if prefix and marker.is_file():
            return Path(prefix)
    return None


def resolve(spec: NodeSpec, variables: Mapping[str, str], prefixes: Sequence[str]) -> Resolved:
    """Find the executable of a graph node.

    Args:
        spec: Graph entry.
        variables: Substitutions for ``command`` (``$PYTHON``, ``$BAG_DIR``, ``$RUN_DIR``).
        prefixes: AMENT_PREFIX_PATH entries.

    Returns:
        READY with the command line; NOT_BUILT when the package is installed without that
        executable; MISSING when the package or the command does not exist; NO_INPUT when
        it exists but a file it requires does not.
    """
    resolved = _resolve_executable(spec, variables, prefixes)
    if resolved.availability is Availability.READY:
        for required in substitute(list(spec.requires), variables):
            if not Path(required).is_file():
                return Resolved(spec, Availability.NO_INPUT, reason=(
                    f'{spec.describe()} needs {required}, which does not exist: skipped'
                ))
    return resolved


def _resolve_executable(
    spec: NodeSpec, variables: Mapping[str, str], prefixes: Sequence[str]
) -> Resolved:
    if spec.command is not None:
        argv = tuple(substitute(list(spec.command), variables))
        program = argv[0]
        found = shutil.which(program) if os.sep not in program else program
        if not found or not Path(found).is_file():
            return Resolved(spec, Availability.MISSING, reason=(
                f'{spec.describe()}: executable {program} not found'
            ))
        return Resolved(spec, Availability.READY, argv=(found, *argv[1:]))
    assert spec.package is not None and spec.executable is not None
    prefix = package_prefix(spec.package, prefixes)
    if prefix is None:
        return Resolved(spec, Availability.MISSING, reason=(
            f'{spec.describe()}: package {spec.package} is not installed '
            '(not in AMENT_PREFIX_PATH; is the workspace built and env.sh sourced?)'
        ))
    exe = prefix / 'lib' / spec.package / spec.executable
    if not (exe.is_file() and os.access(exe, os.X_OK)):
        return Resolved(spec, Availability.NOT_BUILT, reason=(
            f'{spec.describe()} is not built yet: skipped'
        ))
    return Resolved(spec, Availability.READY, argv=(str(exe),))


def node_command(
    resolved: Resolved, params_files: Sequence[Path], sim_time: bool = True
) -> list[str]:
    """Full command line of a ready node, as ``ros2 launch`` would build it.

    Args:
        resolved: A READY node.
        params_files: Params files, later ones override earlier ones.
        sim_time: Pass ``use_sim_time:=true``.
    """
    ros = ['--ros-args', '-r', f'__node:={resolved.spec.name}']
    if sim_time:
        ros += ['-p', 'use_sim_time:=true']
    for params in params_files:
        ros += ['--params-file', str(params)]
    return [*resolved.argv, *ros]
