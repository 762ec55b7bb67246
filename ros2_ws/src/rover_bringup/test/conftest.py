"""Fixtures of the rover_bringup tests: isolated ROS environment, process and SHM hygiene.

Every ROS process a test starts gets its own ROS_DOMAIN_ID and localhost-only discovery
(through the ``ros_env`` fixture), and must be gone when the test ends, without leaving
Fast DDS shared-memory files behind.
"""

from __future__ import annotations

import contextlib
import importlib.util
import itertools
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from types import ModuleType

import psutil
import pytest

HERE = Path(__file__).resolve().parent
SHM = Path('/dev/shm')
_test_counter = itertools.count()


def _load(name: str) -> ModuleType:
    # Tests run with --import-mode=importlib: helper modules next to them are not importable
    # by name, so load them by path under a name no other package uses.
    spec = importlib.util.spec_from_file_location(f'rover_bringup_test_{name}', HERE / f'{name}.py')
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


#: The field-bag writer of the calibration tests, loaded before they are collected: they
#: take it as ``sys.modules['rover_bringup_test_fieldbag']`` at import.
_load('fieldbag')


@pytest.fixture(scope='session')
def bagfactory() -> ModuleType:
    """The test-bag writer module (test/bagfactory.py)."""
    return _load('bagfactory')


def domain_id() -> int:
    """A ROS domain for the next test: distinct per test and per parallel worker."""
    worker = os.environ.get('PYTEST_XDIST_WORKER', 'gw0').removeprefix('gw')
    base = int(worker) * 7 if worker.isdigit() else 0
    return 40 + (os.getpid() + base + next(_test_counter)) % 50


@pytest.fixture
def ros_env() -> dict[str, str]:
    """Environment for ROS subprocesses: ours (unchanged) plus an isolated domain."""
    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(domain_id())
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env.pop('ROS_LOCALHOST_ONLY', None)  # deprecated in Jazzy; would print warnings
    env['PYTHONUNBUFFERED'] = '1'
    return env


@pytest.fixture
def fast_discovery_env(ros_env: dict[str, str]) -> dict[str, str]:
    """``ros_env`` plus a Fast DDS profile announcing participants every 0.5 s."""
    return ros_env | {'FASTRTPS_DEFAULT_PROFILES_FILE': str(HERE / 'fastdds_fast_discovery.xml')}


def _globloc_command() -> list[str]:
    """The installed ``globloc`` console script (as ``ros2 run`` would find it)."""
    for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        exe = Path(prefix) / 'lib' / 'rover_bringup' / 'globloc'
        if prefix and exe.is_file():
            return [str(exe)]
    return [sys.executable, '-m', 'rover_bringup.cli']


@pytest.fixture(scope='session')
def globloc_cmd() -> list[str]:
    """Command line prefix of ``globloc``: the installed console script."""
    return _globloc_command()


GloblocRunner = Callable[..., subprocess.CompletedProcess[str]]


@pytest.fixture(scope='session')
def globloc(globloc_cmd: list[str]) -> GloblocRunner:
    """``globloc(args, env=None, timeout=60)``: run globloc to completion, output captured."""

    def run(
        args: Sequence[str], env: dict[str, str] | None = None, timeout: float = 60.0
    ) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [*globloc_cmd, *args], env=env, capture_output=True, text=True, timeout=timeout,
            check=False,
        )

    return run


def _fastrtps_files() -> set[str]:
    return {p.name for p in SHM.glob('fastrtps_*')}


def _mapped_shm_files() -> set[str]:
    """Names of /dev/shm files some live process has mapped or open (not leaks)."""
    names: set[str] = set()
    for proc_dir in Path('/proc').iterdir():
        if not proc_dir.name.isdigit():
            continue
        try:
            for line in (proc_dir / 'maps').read_text().splitlines():
                if '/dev/shm/' in line:
                    names.add(line.rsplit('/', 1)[-1])
            for fd in (proc_dir / 'fd').iterdir():
                target = os.readlink(fd)
                if target.startswith('/dev/shm/'):
                    names.add(target.rsplit('/', 1)[-1])
        except OSError:
            continue
    return names


def _describe(proc: psutil.Process) -> str:
    """pid and command line of a process that may have exited (or be a zombie) meanwhile."""
    try:
        return f'{proc.pid}: {" ".join(proc.cmdline())}'
    except psutil.Error as exc:
        return f'{proc.pid}: ({type(exc).__name__})'


@pytest.fixture
def sigkill_shm_cleanup() -> Iterator[None]:
    """For a test that SIGKILLs a ROS process on purpose: remove, at the end, the Fast DDS
    shared-memory files that appeared during the test and that no live process uses, as
    ``fastdds shm clean`` would (a SIGKILLed process cannot remove its own). Runs before
    ``no_leftovers`` checks (autouse fixtures are torn down last)."""
    before = _fastrtps_files()
    yield
    time.sleep(0.5)
    for name in _fastrtps_files() - before - _mapped_shm_files():
        with contextlib.suppress(OSError):
            (SHM / name).unlink()


@pytest.fixture(autouse=True)
def no_leftovers() -> Iterator[None]:
    """Fail a test that leaves child processes or Fast DDS shared-memory files behind.

    Only children that appeared during the test count: helpers started earlier in the session
    (such as the multiprocessing resource tracker a spawn-context pool leaves for the life of
    the interpreter) are not this test's leftovers. Leftover children are stopped with SIGTERM
    (SIGKILL would itself leak SHM files). A SHM file counts as leaked when it appeared during
    the test and no live process uses it (other ROS processes on the machine may create their
    own meanwhile).
    """
    me = psutil.Process()
    before_children = {c.pid for c in me.children(recursive=True)}
    before = _fastrtps_files()
    yield
    children = [c for c in me.children(recursive=True)
                if c.pid not in before_children and c.is_running()]
    described = [_describe(c) for c in children]
    for child in children:
        with contextlib.suppress(psutil.NoSuchProcess):
            child.send_signal(signal.SIGTERM)
    _, alive = psutil.wait_procs(children, timeout=10)
    for child in alive:
        with contextlib.suppress(psutil.NoSuchProcess):
            child.kill()
    leaked: set[str] = set()
    deadline = time.monotonic() + 3.0
    while time.monotonic() < deadline:  # Fast DDS removes its files while exiting
        leaked = _fastrtps_files() - before - _mapped_shm_files()
        if not leaked:
            break
        time.sleep(0.2)
    assert not children, f'processes left running: {described}'
    assert not leaked, f'Fast DDS shared-memory files left behind: {sorted(leaked)}'
