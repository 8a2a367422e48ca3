"""A link's first messages, kept for a recorder that attaches after the link opened.

A host program opens its link and sets the robot up (the arm's return delays, limits and
watchdogs; the hand's identification) before a recorder attaches, and what the robot
answers later depends on that setup.  A :class:`Prologue` keeps the first
:data:`PROLOGUE_LIMIT` messages each way with their times; a recorder writes them first, so
a replay of the file starts from the robot the program started from, and the file's
``source`` record says whether they were all kept (``prologue``: ``complete`` or
``partial``).
"""

from __future__ import annotations

from typing import Final

#: Messages a link keeps from its opening (a setup is tens of packets; cycling goes on).
PROLOGUE_LIMIT: Final = 4096


class Prologue:
    """The first messages of a link: ``(direction, t, data)`` with direction ``tx`` or
    ``rx`` and ``t`` the link's clock (s); ``complete`` while none was left out."""

    def __init__(self, limit: int = PROLOGUE_LIMIT) -> None:
        self.limit = limit
        self.messages: list[tuple[str, float, bytes]] = []
        self.complete = True

    def add(self, direction: str, t: float, data: bytes) -> None:
        """Keep one message (or, past the limit, note that the prologue is partial)."""
        if len(self.messages) < self.limit:
            self.messages.append((direction, t, bytes(data)))
        else:
            self.complete = False

    def state(self) -> str:
        """``complete`` or ``partial``, for the recording's ``source`` record."""
        return "complete" if self.complete else "partial"
