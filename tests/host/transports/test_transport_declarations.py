"""Each transport backend declares its own URL schemes and kinds of link (no table of
schemes elsewhere), and the lookups a session makes read those declarations."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator, Mapping
from typing import Any, ClassVar, Final

import pytest

from host.hand.session import LINK_BUDGET_S, Timeouts, first_seq, frame_gap_s
from host.transports import base as registry
from host.transports.base import (
    OTHER_LINK,
    LinkKind,
    Transport,
    link_kind,
    link_of,
    open_transport,
    register_transport,
    schemes,
)

#: What every built-in scheme (and the emulator's) was before the backends declared them.
EXPECTED: Final = {
    "/dev/ttyUSB0": ("serial", 0.100, False), "serial:///dev/ttyS0": ("serial", 0.100, False),
    "spy://x": ("serial", 0.100, False), "loop://": ("loop", 0.030, True),
    "socket://h:1": ("network", 0.250, False), "rfc2217://h:1": ("network", 0.250, False),
    "can://virtual/x": ("can", 0.100, False), "emu://hand/palm": ("in-process", 0.030, True),
    "scripted://": ("other", None, False),
}


@pytest.mark.parametrize("url", list(EXPECTED))
def test_each_scheme_is_the_kind_of_link_its_backend_declares(url: str) -> None:
    kind = link_of(url)
    assert (kind.name, kind.budget_s, kind.exact_timing) == EXPECTED[url]
    assert link_kind(url) == kind.name


def test_the_session_defaults_follow_the_declarations() -> None:
    assert Timeouts.for_url("socket://h:1").link_s == 0.250
    assert Timeouts.for_url("scripted://").link_s == Timeouts().link_s
    assert first_seq("emu://hand/palm") == 0 and first_seq("loop://") == 0
    wide = Timeouts(link_s=0.5)
    assert frame_gap_s("/dev/ttyUSB0", wide) == 0.5
    assert frame_gap_s("emu://hand/palm", wide) < 0.5
    assert dict(LINK_BUDGET_S) == {"serial": 0.100, "can": 0.100, "network": 0.250,
                                   "loop": 0.030, "in-process": 0.030}


class _Echo(Transport):
    """A backend of a scheme of its own (declared by :func:`echo`, inside the test)."""

    def __init__(self, url: str) -> None:
        super().__init__(url)
        self.buffer = b""

    @classmethod
    def from_url(cls, url: str, **options: Any) -> _Echo:
        return cls(url)

    def _send(self, data: bytes) -> None:
        self.buffer += data

    def _recv(self, timeout: float | None) -> bytes:
        out, self.buffer = self.buffer, b""
        return out

    def _close(self) -> None:
        pass


@pytest.fixture
def echo() -> Iterator[type[_Echo]]:
    """A class declaring ``echo-test://`` (registered as it is made), and one inheriting
    the declaration (which does not take the scheme over); both forgotten after."""

    class Declared(_Echo):
        schemes: ClassVar[Mapping[str, LinkKind]] = {
            "echo-test": LinkKind("echo", 0.5, True)}

    class Inheriting(Declared):
        pass

    assert Inheriting.schemes is Declared.schemes
    yield Declared
    registry._declared.pop("echo-test", None)
    registry._registered.pop("echo-late", None)


def test_a_class_that_declares_a_scheme_opens_it(echo: type[_Echo]) -> None:
    assert registry._declared["echo-test"] is echo
    assert "echo-test" in schemes()
    with open_transport("echo-test://x") as t:
        assert type(t) is echo
        t.send(b"ab")
        assert t.recv(0.1) == b"ab"
    assert link_of("echo-test://x") == LinkKind("echo", 0.5, True)
    assert Timeouts.for_url("echo-test://x").link_s == 0.5


def test_a_class_named_by_a_string_is_opened_with_its_from_url(echo: type[_Echo]) -> None:
    """The entry-point group may name the class itself (``module:Class``)."""
    register_transport("echo-late", f"{__name__}:_Echo")
    with open_transport("echo-late://y") as t:
        assert type(t) is _Echo
    assert link_of("echo-late://y") == OTHER_LINK  # it declares no echo-late


def test_registering_a_class_registers_what_it_declares(echo: type[_Echo]) -> None:
    registry._declared.pop("echo-test")
    register_transport(echo)
    assert registry._declared["echo-test"] is echo


def test_looking_schemes_up_does_not_import_python_can() -> None:
    code = ("import sys; from host.transports.base import schemes, link_of; schemes(); "
            "link_of('can://virtual/x'); print('can' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "False"
