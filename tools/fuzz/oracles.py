"""The fuzzer's oracles: what must hold after every step, and the optional introspection.

Wire-level oracles work against any target, emulated or real:

- liveness: the target answers a ping within its deadline (after the inter-frame gap, so a
  truncated frame's partial bytes are dropped first; one retry);
- silence: a frame with a bad CRC or a foreign address draws no reply;
- protected memory: the bootloader pages (with the node identity) hash the same, and
  identify gives the same board, uid and address (bootloader target);
- motors: hall counts do not change unless a valid motion command was sent (fmcb target).

With an :class:`Introspection` (the emulator's ``EmulatorIntrospection``) the same rules are
checked inside: no motor driven without a motion command, the protected pages and the
whole observable state unchanged by a silent frame, no node running an image that does
not verify, no line left driven.  An exception raised inside a firmware model reaches
the fuzzer through the simulation clock and is a failure too.
"""

from __future__ import annotations

from typing import Protocol


class Introspection(Protocol):
    """What an emulated target can tell beyond the wire (see ``hil_emulator.introspection``)."""

    def motors_driven(self) -> list[str]:
        """Names of the motors driven now."""
        ...

    def protected_digest(self) -> bytes:
        """A digest of every node's bootloader pages and identity."""
        ...

    def state_digest(self) -> bytes:
        """A digest of everything a frame could change that the host could observe."""
        ...

    def invariant_violations(self) -> list[str]:
        """Broken internal invariants, described."""
        ...
