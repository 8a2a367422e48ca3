"""Transport URLs: options on bare serial paths as on scheme URLs."""

from __future__ import annotations

from host.transport import url_options, url_scheme


def test_a_bare_path_keeps_its_query_options() -> None:
    assert url_scheme("./robot/arm?baud=1000000") == "serial"
    assert url_options("./robot/arm?baud=1000000") == {"baud": "1000000"}
    assert url_options("/dev/ttyUSB0") == {}


def test_scheme_urls_give_their_options() -> None:
    assert url_scheme("can://slcan/./robot/can?bitrate=500000&node=10") == "can"
    assert url_options("can://slcan/./robot/can?bitrate=500000&node=10") == {
        "bitrate": "500000", "node": "10"}
