"""Spinning a node until SIGINT/SIGTERM, without the shutdown hang of ``rclpy.spin``.

rclpy 7.1 (Jazzy) with Fast DDS: a SIGTERM that lands while the executor is between two
waits is sometimes not seen by the next wait, which ``rclpy.spin`` makes with no timeout; the
process then sleeps forever (measured here: about 1 in 25 SIGTERMs of a node receiving 200
messages/s, stack in ``rcl_wait``), and ``globloc run`` has to SIGKILL it, which loses what it
had not written yet and leaves Fast DDS shared-memory files behind. Waiting in short slices and
checking the context between them bounds the exit delay by the slice.

``run_node`` also keeps rclpy's own signal handlers out: they shut the context down from the
signal, and the node's entities were then destroyed on a dead context. That crashed now and
then (rover_vo, SIGSEGV in ``destroy_subscription`` after a SIGINT, one CI run of two; the
order ros2/launch_ros#213 describes). A signal now only sets a flag; the loop sees it
within one slice, and the node is destroyed before the context is shut down.
"""

from __future__ import annotations

#: Longest wait of one ``spin_once``: the worst-case delay between a signal and the exit.
SLICE_S = 0.2


def spin_until_shutdown(node, slice_s: float = SLICE_S, stop=None) -> None:
    """Execute the node's callbacks until its context is shut down (by a signal or a callback).

    Args:
        node: An ``rclpy.node.Node``; spun by a ``SingleThreadedExecutor`` of its context.
        slice_s: Longest single wait (s).
        stop: Optional ``threading.Event``; the loop also ends, within one slice, once it is
            set (``run_node``'s signal handlers set it).

    Returns normally on shutdown, including when the context goes invalid mid-wait (rclpy
    then raises ``ExternalShutdownException`` or ``RCLError``, which are absorbed here only
    when the context is indeed shut down).
    """
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    context = node.context
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        while context.ok() and not (stop is not None and stop.is_set()):
            try:
                executor.spin_once(timeout_sec=slice_s)
            except ExternalShutdownException:
                break
            except Exception:
                if context.ok():
                    raise
                break  # the context went away while the wait set was being built
    finally:
        executor.shutdown(timeout_sec=0)


def run_node(node_factory, name: str, args: list[str] | None = None,
             error_status: int = 1) -> int:
    """The process around one node: init, spin until SIGINT/SIGTERM, shut down.

    Every node executable of the graph ends its ``main`` with this, so that they all stop
    and fail the same way.

    Args:
        node_factory: Called with no argument after ``rclpy.init``; returns the node.
        name: Executable name, first word of the error line.
        args: ROS arguments (``--ros-args ...``), as ``rclpy.init`` takes them.
        error_status: Exit status when the node cannot start.

    Returns:
        0 on a stop by signal, including one that lands while the node is still starting;
        ``error_status`` after printing ``<name>: error: <reason>`` to stderr when the node
        cannot start (bad parameter, unreadable input file: ``OSError``, ``ValueError``).
    """
    import signal
    import sys
    import threading

    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.signals import SignalHandlerOptions

    stop = threading.Event()
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    previous = {sig: signal.signal(sig, lambda _sig, _frame: stop.set())
                for sig in (signal.SIGINT, signal.SIGTERM)}
    node = None
    try:
        node = node_factory()
        spin_until_shutdown(node, stop=stop)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (OSError, ValueError) as exc:
        print(f"{name}: error: {exc}", file=sys.stderr)
        return error_status
    except Exception:
        # The context shut down while the node was starting (by a callback or another
        # thread; a signal only sets ``stop``): rclpy then fails to create the remaining
        # entities. That is a stop, not a crash.
        if rclpy.ok():
            raise
        return 0
    finally:
        # The node goes first, while its context is still valid; the signals stay caught
        # until the context is down, so that a second Ctrl-C cannot cut this short.
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0
