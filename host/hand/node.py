"""One board of the hand the host can talk to: the palm, or a finger's fmcb, f2 or f3.

A :class:`Node` is a :class:`~host.hand.session.HandSession` and a
:class:`~host.hand.session.Target`: requests to it go through the palm's link to that
board (:meth:`Node.request` waits for the reply, :meth:`Node.start` does not).
"""

from __future__ import annotations

from typing import Any

from host.code_names import code_name
from host.hand.session import HandSession, PendingReply, Target
from host.hand.state import NodeInfo
from protocol.messages import CATALOGUE_HASH
from protocol.messages.common import Running


class Node:
    """One board the host can talk to: the palm, or a finger's fmcb / f2 / f3."""

    def __init__(self, session: HandSession, target: Target, where: str) -> None:
        self.session = session
        self.target = target
        self.where = where

    def request(self, name: str, fields: dict[str, Any] | None = None,
                **options: Any) -> dict[str, Any]:
        """Request ``name`` of this node (see :meth:`HandSession.request` for options)."""
        return self.session.request(name, fields, to=self.target, **options)

    def start(self, name: str, fields: dict[str, Any] | None = None,
              **options: Any) -> PendingReply:
        """Send request ``name`` to this node without waiting (:meth:`HandSession.wait`)."""
        return self.session.start(name, fields, to=self.target, **options)

    def ping(self) -> None:
        """Ask the node to answer (raises if it does not)."""
        self.request("ping")

    def identify(self) -> NodeInfo:
        """Who answers here: running program, board, versions (:class:`NodeInfo`)."""
        return self._info(self.request("identify"))

    def _info(self, reply: dict[str, Any]) -> NodeInfo:
        v = reply["fw_version"]
        return NodeInfo(
            where=self.where, finger=self.target.finger,
            hop=None if self.where == "palm" else self.target.hop, answered=True,
            running=code_name(Running, reply["running"], "running"), board=reply["board"],
            address=reply["address"], fw_version=f"{v['major']}.{v['minor']}.{v['patch']}",
            hw_version=reply["hw_version"], uid=reply["uid"],
            catalogue_matches=bytes(reply["catalogue"]) == CATALOGUE_HASH)

    def __repr__(self) -> str:
        return f"Node({self.where})"
