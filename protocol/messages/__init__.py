"""The hand's message catalogue: every message of every hand node, declared once.

``CATALOGUE`` is the single registry; ``CATALOGUE_HASH`` its 8-byte fingerprint, carried
by the identify reply.
"""

from __future__ import annotations

from protocol.catalogue import Catalogue
from protocol.messages import boot_program, common, fmcb, palm, phalange, slots

CATALOGUE = Catalogue(
    [*common.MESSAGES, *palm.MESSAGES, *fmcb.MESSAGES, *phalange.MESSAGES, *boot_program.MESSAGES,
     *slots.MESSAGES]
)
CATALOGUE_HASH: bytes = CATALOGUE.fingerprint()

__all__ = ["CATALOGUE", "CATALOGUE_HASH"]
