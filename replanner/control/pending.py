"""PENDING's bookkeeping: the path ahead is blocked, a replan is on its way, and the path may clear first."""

from __future__ import annotations


class Pending:
    """Made on entering PENDING and dropped on leaving it.

    Args:
        since: when the path was found blocked [controller clock s].
    """

    def __init__(self, since: float):
        self.since = since
        self.clear_count = 0  # checks in a row the path was clear
        self.retry_at: float | None = None  # when to plan again after a blocked goal [s]; None: no retry waits

    def count(self, clear: bool) -> int:
        """One more check, clear or not: the checks in a row the path was clear."""
        self.clear_count = self.clear_count + 1 if clear else 0
        return self.clear_count

    def retry_due(self, now: float) -> bool:
        """Whether a retry waits and is due now (it is then taken)."""
        if self.retry_at is None or now < self.retry_at:
            return False
        self.retry_at = None
        return True
