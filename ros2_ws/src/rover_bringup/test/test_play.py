"""``globloc play`` into a subscriber in another process: every message, in order, with /clock.

The subscriber (capture_node.py) uses the QoS a real consumer would: best effort for the
sensor streams, reliable for the ground truth and /clock. Delivery figures are printed
(``pytest -s``) and quoted in docs/bringup.md.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

pytestmark = pytest.mark.ros

HERE = Path(__file__).resolve().parent


def _capture(
    tmp_path: Path, env: dict[str, str], expected: dict[str, list], clock_until: int
) -> tuple[subprocess.Popen[bytes], Path]:
    out = tmp_path / 'capture.json'
    argv = [
        sys.executable, str(HERE / 'capture_node.py'), str(out),
        '--expect', *(f'{t}={len(v)}' for t, v in expected.items()),
        '--clock-until', str(clock_until), '--timeout', '60',
    ]
    return subprocess.Popen(argv, env=env), out


def _play_into_capture(
    tmp_path: Path,
    env: dict[str, str],
    globloc_cmd: list[str],
    bag: Path,
    expected: dict[str, list],
    clock_range: tuple[int, int],
    play_args: list[str],
) -> tuple[dict[str, Any], str]:
    """Start the capture, play the bag, return (capture JSON, player stderr)."""
    capture, out = _capture(tmp_path, env, expected, clock_range[1])
    try:
        player = subprocess.run(
            [*globloc_cmd, 'play', str(bag), '--wait-subscribers', '30', *play_args],
            env=env, capture_output=True, text=True, timeout=120, check=False,
        )
        assert capture.wait(timeout=90) == 0
    finally:
        if capture.poll() is None:
            capture.terminate()
            try:
                capture.wait(timeout=10)
            except subprocess.TimeoutExpired:
                capture.kill()  # rclpy handles SIGTERM itself; a hung one ignores it
                capture.wait(timeout=10)
    assert player.returncode == 0, player.stderr
    assert 'Traceback' not in player.stderr
    return json.loads(out.read_text()), player.stderr


def _check(
    received: dict[str, Any], expected: dict[str, list], clock_range: tuple[int, int], label: str
) -> None:
    sent = sum(len(v) for v in expected.values())
    got = sum(len(received['topics'].get(t, [])) for t in expected)
    per_topic = ', '.join(
        f'{t} {len(received["topics"].get(t, []))}/{len(v)}' for t, v in expected.items()
    )
    print(f'\nDELIVERY {label}: sent {sent}, received {got} ({per_topic}); '
          f'/clock {len(received["clock"])} msgs')
    for topic, messages in expected.items():
        # Content and per-topic order: stamps, sequence numbers, image hashes.
        assert received['topics'][topic] == messages, topic
    clock = received['clock']
    assert clock == sorted(clock) and len(set(clock)) == len(clock), '/clock not monotonic'
    assert clock[0] == clock_range[0] and clock[-1] == clock_range[1], '/clock does not cover'


def _stamp_range(expected: dict[str, list]) -> tuple[int, int]:
    stamps = [m['stamp'] for v in expected.values() for m in v]
    return min(stamps), max(stamps)


def test_play_rate_10_delivers_every_message(
    tmp_path: Path, bagfactory: ModuleType, ros_env: dict[str, str], globloc_cmd: list[str]
):
    # Project layout: bags/<name>/rosbag/ (the player is given bags/<name>/).
    spec = bagfactory.write_bag(tmp_path / 'bags' / 'quick' / 'rosbag')
    assert [len(v) for v in spec.expected.values()] == [1000, 100, 100]
    clock_range = _stamp_range(spec.expected)
    received, stderr = _play_into_capture(
        tmp_path, ros_env, globloc_cmd, tmp_path / 'bags' / 'quick', spec.expected,
        clock_range, ['--rate', '10'],
    )
    _check(received, spec.expected, clock_range, 'rate 10 (1000 IMU + 100 images + 100 poses)')
    assert 'done: bag time 9.99/9.99 s (100%), 1200 msgs sent' in stderr
    # /clock at most once per 10 ms of wall time (play.CLOCK_HZ, 100), not once per message:
    # 1200 messages in ~1 s of wall time give ~100 ticks, never one per distinct stamp.
    distinct = len({m['stamp'] for v in spec.expected.values() for m in v})
    assert len(received['clock']) < distinct / 2, len(received['clock'])


def test_play_rate_1_short_bag(
    tmp_path: Path, bagfactory: ModuleType, ros_env: dict[str, str], globloc_cmd: list[str]
):
    spec = bagfactory.write_bag(tmp_path / 'short', bagfactory.BagSpec(duration_s=2.0))
    clock_range = _stamp_range(spec.expected)
    received, stderr = _play_into_capture(
        tmp_path, ros_env, globloc_cmd, tmp_path / 'short', spec.expected, clock_range,
        ['--rate', '1'],
    )
    _check(received, spec.expected, clock_range, 'rate 1, 2 s bag')
    # The summary line.
    assert '%), ' in stderr and 'msgs sent' in stderr
    # At rate 1 /clock ticks at play.CLOCK_HZ (100) through the 2 s, messages or not: about
    # 200 ticks, each within 10 ms of wall time of the previous one (some slack for a
    # loaded machine), never more than one per 10 ms.
    clock = received['clock']
    assert 50 <= len(clock) <= 2.0 * 100 + 5, len(clock)


def test_play_sqlite_bag_with_start_and_topics_as_fast_as_possible(
    tmp_path: Path, bagfactory: ModuleType, ros_env: dict[str, str], globloc_cmd: list[str]
):
    spec = bagfactory.write_bag(
        tmp_path / 'db', bagfactory.BagSpec(duration_s=2.0, storage='sqlite3')
    )
    start = bagfactory.T0_NS + 1_000_000_000
    topics = [bagfactory.IMU_TOPIC, bagfactory.POSE_TOPIC]
    expected = {t: [m for m in spec.expected[t] if m['stamp'] >= start] for t in topics}
    assert [len(v) for v in expected.values()] == [100, 10]
    clock_range = (start, _stamp_range(expected)[1])
    received, _ = _play_into_capture(
        tmp_path, ros_env, globloc_cmd, tmp_path / 'db', expected, clock_range,
        ['--rate', '0', '--start', '1', '--topics', *topics],
    )
    _check(received, expected, clock_range, 'rate 0 (as fast as possible), sqlite3')


@pytest.mark.parametrize('shut_down', [True, False])
def test_rcl_error_after_a_signal_is_an_interruption(
    tmp_path: Path, bagfactory: ModuleType, ros_env: dict[str, str], monkeypatch, shut_down: bool
):
    """A signal shuts the context down between two rcl calls of the player (CI once saw
    get_subscription_count raise RCLError "publisher's context is invalid" after the last
    message): that is the interruption it is, exit 130, not a traceback. The same error with
    the context still up is a real failure and propagates."""
    import rclpy

    from rover_bringup import play as play_module

    for key in ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE'):
        monkeypatch.setenv(key, ros_env[key])
    bagfactory.write_bag(tmp_path / 'bag', bagfactory.BagSpec(duration_s=0.1))

    def racing_play(player, *args):
        if shut_down:
            rclpy.shutdown(context=player.context)  # what the SIGINT handler does
        raise RuntimeError("failed to get subscription count: publisher's context is invalid")

    monkeypatch.setattr(play_module, '_play', racing_play)
    options = play_module.PlayOptions(bag=tmp_path / 'bag', wait_timeout_s=0)
    if shut_down:
        assert play_module.play(options) == play_module.EXIT_INTERRUPTED
    else:
        with pytest.raises(RuntimeError, match='context is invalid'):
            play_module.play(options)
    assert not rclpy.ok()
