"""Restart of graph nodes that die mid-run (``ros2 launch``'s ``respawn``), with a limit.

A node that exits while the run still needs it (it was not asked to stop) is started again
with the same command line, its log appended to (a marker line separates the runs), until
it has been restarted ``max_restarts`` times; after that its exit ends the run as before.
The recorder and the player are never restarted: a new recorder would start a new bag,
and the player's position in the bag is not kept. Once the run is interrupted (SIGINT or
SIGTERM, ``Respawner.stopped``) nothing is restarted: the nodes' exits are the stop.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from rover_bringup.errors import say
from rover_bringup.launcher import ManagedProcess, start


@dataclass
class Respawner:
    """Restarts nodes; call it with a process that exited on its own.

    Attributes:
        max_restarts: restarts allowed per node (0: never restart).
        log_dir: directory of the logs.
        processes: the run's processes by name (the restarted one replaces the old).
        nodes: names of the processes that may be restarted.
        exits: per node, the exit status of each incarnation that was restarted.
        stopped: set when the run is being stopped (an interrupt): restart nothing.
    """

    max_restarts: int
    log_dir: Path
    processes: dict[str, ManagedProcess]
    nodes: set[str]
    exits: dict[str, list[int]] = field(default_factory=dict)
    stopped: bool = False

    def __call__(self, proc: ManagedProcess) -> ManagedProcess | None:
        """Restart ``proc``; None when it may not be (not a node, out of restarts, or the
        run is stopping)."""
        if self.stopped or proc.name not in self.nodes:
            return None
        codes = self.exits.setdefault(proc.name, [])
        if len(codes) >= self.max_restarts:
            return None
        codes.append(proc.returncode)
        proc.close_log()
        message = (f'{proc.name} exited (status {proc.returncode}) while running: restarting '
                   f'it ({len(codes)} of at most {self.max_restarts}; log {proc.log_path})')
        say(f'globloc: warning: {message}')
        with proc.log_path.open('ab') as fh:
            fh.write(f'\n[globloc] {message}\n\n'.encode())
        new = start(proc.name, proc.argv, self.log_dir, append=True)
        self.processes[proc.name] = new
        return new
