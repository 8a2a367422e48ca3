"""Messages every hand node understands, application or bootloader.

Original ids: ping 0x01, reset 0x09, hardware version 0xFA.  New ids (0x60 …): identify,
which carries the catalogue fingerprint so a host detects firmware speaking another version
of the catalogue, and the transaction envelope, whose reply names its sender and the
request it answers (the original matched replies by type only).
"""

from __future__ import annotations

from enum import IntEnum

import construct as c

from protocol.catalogue import Message
from protocol.enum_field import EnumField
from protocol.image import BoardType
from protocol.messages.fields import EMPTY, VERSION


class TxnStatus(IntEnum):
    """Status of a ``txn`` reply: did the wrapped request get an answer."""

    OK = 0
    UNKNOWN_TYPE = 1
    BAD_PAYLOAD = 2
    BUSY = 3
    NO_REPLY = 4
    REFUSED = 5


class Running(IntEnum):
    """Which program answers an ``identify``."""

    BOOTLOADER = 0
    APPLICATION = 1


#: The board type of the node that answers (protocol.image.BoardType).
BOARD = EnumField(c.Int8ul, BoardType)

IDENTIFY_REPLY = c.Struct(
    "board" / BOARD * "[-] board type",
    "address" / c.Int8ul * "[-] the node's bus address (from its identity page)",
    "running" / EnumField(c.Int8ul, Running) * "[-] the program that answers",
    "hw_version" / c.Int32ul * "[-] hardware version word (0xBEEF0041 fingers)",
    "fw_version" / VERSION * "[-] version of the running program",
    "catalogue" / c.Bytes(8) * "[-] first 8 bytes of SHA-256 of the message catalogue",
    "uid" / c.Int32ul * "[-] unique id of this microcontroller",
    "uptime_us" / c.Int32ul * "[µs] time since reset (wraps after ~71 min)",
)

TXN_REQUEST = c.Struct(
    "seq" / c.Int8ul * "[-] sequence number chosen by the host, echoed in the reply",
    "inner_type" / c.Int8ul * "[-] message type of the wrapped request",
    "inner" / c.GreedyBytes * "[-] payload of the wrapped request",
)

TXN_REPLY = c.Struct(
    "seq" / c.Int8ul * "[-] the request's sequence number",
    "board" / BOARD * "[-] board type of the node that answers",
    "address" / c.Int8ul * "[-] bus address of the node that answers",
    "inner_type" / c.Int8ul * "[-] message type of the request answered",
    "status" / EnumField(c.Int8ul, TxnStatus) * "[-] outcome of the wrapped request",
    "inner" / c.GreedyBytes * "[-] reply payload of the wrapped message (empty unless ok)",
)

MESSAGES: list[Message] = [
    Message("ping", "common", 0x01, EMPTY, EMPTY, "Is anybody there? Empty reply."),
    Message("reset", "common", 0x09, EMPTY, EMPTY, "Acknowledge, then reset the node."),
    Message(
        "hw_version",
        "common",
        0xFA,
        EMPTY,
        c.Struct("version" / c.Int32ul * "[-] hardware version word"),
        "Hardware version word (0xBEEF0041 fingers; 0xBEEF4C41 / 0xBEEF5241 left/right palm).",
    ),
    Message(
        "identify",
        "common",
        0x60,
        EMPTY,
        IDENTIFY_REPLY,
        "Who are you: board, address, program, versions and catalogue fingerprint.",
        original=False,
    ),
    Message(
        "txn",
        "common",
        0x61,
        TXN_REQUEST,
        TXN_REPLY,
        "Transaction envelope: any request with a sequence number; the reply names sender and "
        "request.",
        original=False,
    ),
]
