"""User errors: one line, exit status 2, no traceback."""

from __future__ import annotations

import sys
from typing import Callable


class UserError(Exception):
    """A problem with the user's input, reported as one line (exit status 2)."""


def run_main(body: Callable[[], int]) -> int:
    """Run a command body; turn a `UserError` into one line on stderr and status 2."""
    try:
        return body()
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
