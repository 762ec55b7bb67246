"""``globloc eval RUN_DIR``: evaluate a run and write report.json, report.md and plots.

``report.json`` carries the run's own status (``run_status``: ok, degraded, failed or
interrupted, and why, from ``run.yaml``) beside the figures, so that a degraded run's
numbers are never read as a clean run's."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from roi_network.files import write_atomic
from rover_bringup.evaluation import evaluate, load_run, report_markdown
from rover_bringup.run_outputs import run_status

REPORT_JSON = 'report.json'
REPORT_MD = 'report.md'
PLOTS = ('route.png', 'error.png')


@dataclass
class EvalOptions:
    """What ``globloc eval`` does.

    Attributes:
        run_dir: ``out/<bag>/<run>/``.
        bag: The bag directory (None: the one recorded in ``run.yaml``).
        plots: Draw the plots.
    """

    run_dir: Path
    bag: Path | None = None
    plots: bool = True


def evaluate_run(options: EvalOptions) -> dict:
    """Evaluate a run and write its report files (report.json, report.md, the plots).

    Returns:
        The report (report.json's content), also when nothing was localized: the report
        says so.

    Raises:
        GloblocError: Bad run directory, missing truth, unreadable files (named).
    """
    data = load_run(options.run_dir, options.bag)
    ev = evaluate(data)
    plots = []
    if options.plots:
        from rover_bringup.plots import plot_error, plot_route

        plot_route(ev, data, options.run_dir / PLOTS[0])
        plot_error(ev, options.run_dir / PLOTS[1])
        plots = list(PLOTS)
    summary = ev.summary | {'plots': plots, 'run_status': run_status(options.run_dir)}
    write_atomic(options.run_dir / REPORT_JSON, report_json(summary))
    write_atomic(options.run_dir / REPORT_MD, report_markdown(summary, plots))
    return summary


def report_json(summary: dict) -> str:
    """report.json's text."""
    return json.dumps(summary, indent=2, sort_keys=False) + '\n'

