"""``globloc eval RUN_DIR``: evaluate a run and write report.json, report.md and plots."""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path

from roi_network.files import write_atomic
from rover_bringup.evaluation import evaluate, load_run, report_markdown, summary_lines

REPORT_JSON = 'report.json'
REPORT_MD = 'report.md'
PLOTS = ('route.png', 'error.png')


@dataclass
class EvalOptions:
    """What ``globloc eval`` does.

    Attributes:
        run_dir: ``out/<bag>/<run>/``.
        bag: The bag directory (None: the one recorded in ``run.yaml``).
        json: Print report.json to stdout instead of the summary lines.
        plots: Draw the plots.
    """

    run_dir: Path
    bag: Path | None = None
    json: bool = False
    plots: bool = True


def evaluate_run(options: EvalOptions) -> int:
    """Evaluate a run; write its report files; print the summary (or the JSON).

    Returns:
        0 (also when nothing was localized: the report says so).

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
    summary = ev.summary | {'plots': plots}
    text = json.dumps(summary, indent=2, sort_keys=False)
    write_atomic(options.run_dir / REPORT_JSON, text + '\n')
    write_atomic(options.run_dir / REPORT_MD, report_markdown(summary, plots))
    if options.json:
        print(text)
    else:
        for line in summary_lines(summary):
            print(line)
        print(f'report: {options.run_dir / REPORT_MD}', file=sys.stderr)
    return 0
