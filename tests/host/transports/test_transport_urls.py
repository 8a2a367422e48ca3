"""Transport URLs: options on bare serial paths as on scheme URLs."""

from __future__ import annotations

import pytest

from host.errors import TransportError, UsageError
from host.transports.base import open_transport, url_options, url_scheme


def test_a_bare_path_keeps_its_query_options() -> None:
    assert url_scheme("./robot/arm?baud=1000000") == "serial"
    assert url_options("./robot/arm?baud=1000000") == {"baud": "1000000"}
    assert url_options("/dev/ttyUSB0") == {}


def test_scheme_urls_give_their_options() -> None:
    assert url_scheme("can://slcan/./robot/can?bitrate=500000&node=10") == "can"
    assert url_options("can://slcan/./robot/can?bitrate=500000&node=10") == {
        "bitrate": "500000", "node": "10"}


def test_an_unknown_can_interface_is_a_usage_error_naming_the_known_ones() -> None:
    with pytest.raises(UsageError, match="no CAN interface 'sockcan'; python-can knows .*"
                                         "socketcan"):
        open_transport("can://sockcan/can0")


def test_a_socketcan_interface_that_will_not_open_says_what_to_check() -> None:
    with pytest.raises(TransportError, match="ip link show nosuchcan9"):
        open_transport("can://socketcan/nosuchcan9")


def test_a_url_option_its_backend_cannot_read_is_a_usage_error() -> None:
    with pytest.raises(UsageError, match=r"emu://hand/palm\?seed=abc: seed=.abc. is not an integer"):
        open_transport("emu://hand/palm?seed=abc")
