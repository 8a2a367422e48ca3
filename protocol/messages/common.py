"""Messages every hand node understands, application or bootloader.

Original ids: ping 0x01, reset 0x09, hardware version 0xFA.  New ids (0x60 …): identify,
which carries the catalogue fingerprint so a host detects firmware speaking another version
of the catalogue, and the transaction envelope, whose reply names its sender and the
request it answers (the original matched replies by type only).
"""

from __future__ import annotations

import construct as c

from protocol.catalogue import Message
from protocol.messages.fields import EMPTY, VERSION

#: Status codes of a transaction reply.
TXN_STATUS = {
    0: "ok",
    1: "unknown_type",
    2: "bad_payload",
    3: "busy",
    4: "no_reply",
    5: "refused",
}

#: Running-state codes in an identify reply.
RUNNING = {0: "bootloader", 1: "application"}

IDENTIFY_REPLY = c.Struct(
    "board" / c.Int8ul * "[-] board type (protocol.image.BoardType: 1 palm, 2 fmcb, 3 f2, 4 f3)",
    "address" / c.Int8ul * "[-] the node's bus address (from its identity page)",
    "running" / c.Int8ul * "[-] 0 bootloader, 1 application",
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
    "board" / c.Int8ul * "[-] board type of the node that answers",
    "address" / c.Int8ul * "[-] bus address of the node that answers",
    "inner_type" / c.Int8ul * "[-] message type of the request answered",
    "status" / c.Int8ul * "[-] 0 ok, 1 unknown type, 2 bad payload, 3 busy, 4 no reply, 5 refused",
    "inner" / c.GreedyBytes * "[-] reply payload of the wrapped message (empty unless ok)",
)

MESSAGES = [
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
