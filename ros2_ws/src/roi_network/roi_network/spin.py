"""Spinning a node until SIGINT/SIGTERM, without the shutdown hang of ``rclpy.spin``.

rclpy 7.1 (Jazzy) with Fast DDS: a SIGTERM that lands while the executor is between two
waits is sometimes not seen by the next wait, which ``rclpy.spin`` makes with no timeout; the
process then sleeps forever (measured here: about 1 in 25 SIGTERMs of a node receiving 200
messages/s, stack in ``rcl_wait``), and ``globloc run`` has to SIGKILL it, which loses what it
had not written yet and leaves Fast DDS shared-memory files behind. Waiting in short slices and
checking the context between them bounds the exit delay by the slice.
"""

from __future__ import annotations

#: Longest wait of one ``spin_once``: the worst-case delay between a signal and the exit.
SLICE_S = 0.2


def spin_until_shutdown(node, slice_s: float = SLICE_S) -> None:
    """Execute the node's callbacks until its context is shut down (by a signal or a callback).

    Args:
        node: An ``rclpy.node.Node``; spun by a ``SingleThreadedExecutor`` of its context.
        slice_s: Longest single wait (s).

    Returns normally on shutdown, including when the context goes invalid mid-wait (rclpy
    then raises ``ExternalShutdownException`` or ``RCLError``, which are absorbed here only
    when the context is indeed shut down).
    """
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    context = node.context
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        while context.ok():
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
    import sys

    import rclpy
    from rclpy.executors import ExternalShutdownException

    rclpy.init(args=args)
    node = None
    try:
        node = node_factory()
        spin_until_shutdown(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (OSError, ValueError) as exc:
        print(f"{name}: error: {exc}", file=sys.stderr)
        return error_status
    except Exception:
        # Asked to stop while starting: rclpy then fails to create the remaining entities
        # on the shut-down context. That is a stop, not a crash.
        if rclpy.ok():
            raise
        return 0
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
