"""Fixtures shared by the roi_detector tests."""

from __future__ import annotations

from types import SimpleNamespace

import pytest


@pytest.fixture
def run_cli(capsys):
    """``roi_detector ARGS`` run in this process (the console script's ``main``, without a
    new interpreter's start per call): ``run_cli(*args)`` -> returncode, stdout, stderr."""
    from roi_detector import cli

    def run(*args):
        capsys.readouterr()
        rc = cli.main([str(a) for a in args])
        out = capsys.readouterr()
        return SimpleNamespace(returncode=rc, stdout=out.out, stderr=out.err)
    return run
