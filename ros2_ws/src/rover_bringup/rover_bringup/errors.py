"""The one exception type for user errors (bad bag, bad graph file, missing executable...).

The CLI prints it as a single ``globloc: error: <message>`` line and exits non-zero; anything
else escaping is a bug and keeps its traceback.
"""


class GloblocError(Exception):
    """A user-facing error: the message is the whole explanation, no traceback is shown."""
