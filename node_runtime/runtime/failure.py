"""How a failed node tells why: its account, written once, read by whoever started it.

A node process (``process.py``) and an in-process host (``driver.py``) fail the same way: the exception
becomes one account, 'Type: message' then the traceback, which the fork server (``forkserver.py``) hands
to the orchestrator and an in-process simulation puts in its error. It lives below all three, so that
none of them imports another for it.
"""

from __future__ import annotations

import traceback


class ChildFailed(Exception):
    """Raised by a node whose failure is already written up: its message is the whole account."""


def account(exc: BaseException) -> str:
    """What a failed node tells its parent: 'Type: message', then the traceback."""
    if isinstance(exc, ChildFailed):
        return str(exc)
    return f"{type(exc).__name__}: {exc}\n{''.join(traceback.format_exception(exc))}"
