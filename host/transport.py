"""One abstract transport and a lazy registry of backends chosen by URL.

A :class:`Transport` moves bytes of one link: the palm's USB serial port, a loose finger's
cable, the arm's RS-485 adapter, the palm's CAN bus, or an emulated robot in the same
process.  The public methods own the checks (closed, timeouts); backends implement the
private ``_send`` / ``_recv`` / ``_close``, as python-can's ``BusABC`` does.

Time: :meth:`Transport.now` is the link's clock in seconds.  Real links use the wall clock
(``time.monotonic``); an in-process emulator's transport uses the simulation clock, and
waiting in :meth:`Transport.recv` advances the simulation, so host code written once runs
against a real robot, the emulator's ptys, or the emulator in fast mode.

URLs (:func:`open_transport`):

=================================  ==================================================
``/dev/ttyUSB0``, ``./robot/palm``  a serial port by path (pyserial), ``?baud=N``
``serial:///dev/ttyUSB0``           the same, explicitly
``socket://host:port``,             any pyserial URL handler (``rfc2217://``,
``loop://``, ``spy://…``            ``loop://`` for tests, ``spy://`` to hexdump)
``can://slcan/./robot/can``         python-can: ``can://INTERFACE/CHANNEL``, options
``can://socketcan/can0``            ``?bitrate=1000000&node=10``
``can://virtual/bench``
``emu://…``                         the emulator in process (registered by the emulator)
=================================  ==================================================

Backends are imported only when a URL needs them.  Other packages add schemes with
:func:`register_transport` or the ``lowcost_hand.transports`` entry-point group.
"""

from __future__ import annotations

import importlib
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from importlib import metadata
from typing import Any, Final
from urllib.parse import parse_qsl, urlsplit

from host.errors import TransportError, UsageError

#: Entry-point group through which other packages register transport schemes.
ENTRY_POINT_GROUP: Final = "lowcost_hand.transports"
#: Default serial rate of hand links (palm USB port, loose-finger cable), bit/s.
HAND_SERIAL_BAUD: Final = 2_000_000


class Transport(ABC):
    """Bytes to and from one link.  A context manager; :meth:`close` is idempotent.

    :meth:`send` takes whole frames (a CAN backend cuts each into CAN frames);
    :meth:`recv` returns the bytes that arrived, or ``b""`` when ``timeout`` (seconds on
    :meth:`now`'s clock) passed without any.
    """

    def __init__(self, url: str) -> None:
        self.url = url
        self._closed = False

    # -- public API: checks here, work in the backends
    def send(self, data: bytes) -> None:
        """Send ``data`` (one or more whole frames)."""
        self._require_open()
        self._send(bytes(data))

    def recv(self, timeout: float | None = 0.0) -> bytes:
        """Bytes received, waiting at most ``timeout`` s (None: until some arrive)."""
        self._require_open()
        if timeout is not None and timeout < 0:
            timeout = 0.0
        return self._recv(timeout)

    def now(self) -> float:
        """The link's clock (s): wall-clock monotonic time, or the simulation's."""
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` pass on the link's clock (bytes arriving meanwhile are kept)."""
        if seconds > 0:
            time.sleep(seconds)

    def close(self) -> None:
        """Release the link (idempotent)."""
        if not self._closed:
            self._closed = True
            self._close()

    def reopen(self) -> None:
        """Open the link again after :meth:`close` or a :class:`TransportError` (a USB
        adapter plugged back in); raises :class:`TransportError` if it is still gone."""
        self.close()
        self._reopen()
        self._closed = False

    @property
    def closed(self) -> bool:
        """True once :meth:`close` ran."""
        return self._closed

    def __enter__(self) -> Transport:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.url!r}{', closed' if self._closed else ''})"

    def _require_open(self) -> None:
        if self._closed:
            raise TransportError(f"{self.url}: the transport is closed")

    # -- backends implement these
    @abstractmethod
    def _send(self, data: bytes) -> None: ...

    @abstractmethod
    def _recv(self, timeout: float | None) -> bytes: ...

    @abstractmethod
    def _close(self) -> None: ...

    def _reopen(self) -> None:
        raise TransportError(f"{self.url}: this transport cannot be reopened")


TransportFactory = Callable[..., Transport]

#: Built-in schemes → "module:attribute" of a factory ``f(url, **options) -> Transport``.
_BUILTIN: Final[dict[str, str]] = {
    "serial": "host.transports.serial_port:SerialTransport.from_url",
    "socket": "host.transports.serial_port:SerialTransport.from_url",
    "rfc2217": "host.transports.serial_port:SerialTransport.from_url",
    "loop": "host.transports.serial_port:SerialTransport.from_url",
    "spy": "host.transports.serial_port:SerialTransport.from_url",
    "can": "host.transports.can_bus:CanTransport.from_url",
}
_registered: dict[str, TransportFactory | str] = {}


def register_transport(scheme: str, factory: TransportFactory | str) -> None:
    """Make ``scheme://…`` URLs open with ``factory`` (a callable, or ``"module:attr"``
    imported on first use)."""
    _registered[scheme.lower()] = factory


def _resolve(target: TransportFactory | str) -> TransportFactory:
    if not isinstance(target, str):
        return target
    module_name, _, attr_path = target.partition(":")
    obj: Any = importlib.import_module(module_name)
    for attr in attr_path.split("."):
        obj = getattr(obj, attr)
    return obj  # type: ignore[no-any-return]


def _from_entry_points(scheme: str) -> TransportFactory | None:
    for entry in metadata.entry_points(group=ENTRY_POINT_GROUP):
        if entry.name == scheme:
            return entry.load()  # type: ignore[no-any-return]
    return None


def url_scheme(url: str) -> str:
    """The scheme of a transport URL; a bare path (no ``://``) is ``serial``."""
    if "://" not in url:
        return "serial"
    return url.split("://", 1)[0].lower()


#: What kind of link each built-in scheme is, for timing defaults (:func:`link_kind`).
_KINDS: Final[dict[str, str]] = {
    "serial": "serial", "spy": "serial", "loop": "loop", "socket": "network",
    "rfc2217": "network", "can": "can", "emu": "in-process",
}


def link_kind(url: str) -> str:
    """``"serial"`` (a device or pty: USB adapters buffer up to their latency timer, 16 ms
    by default), ``"can"``, ``"network"`` (``socket://``, ``rfc2217://``), ``"loop"``,
    ``"in-process"`` (``emu://``: the simulation clock, exact wire times), or ``"other"``
    for a scheme registered by another package."""
    return _KINDS.get(url_scheme(url), "other")


def url_options(url: str) -> dict[str, str]:
    """The ``?key=value`` options of a URL or of a path (``/dev/ttyUSB0?baud=1000000``)."""
    if "://" in url:
        return dict(parse_qsl(urlsplit(url).query))
    return dict(parse_qsl(url.split("?", 1)[1])) if "?" in url else {}


def schemes() -> list[str]:
    """Every scheme :func:`open_transport` knows now (built-in, registered, entry points)."""
    found = set(_BUILTIN) | set(_registered)
    found |= {e.name for e in metadata.entry_points(group=ENTRY_POINT_GROUP)}
    return sorted(found)


def open_transport(url: str, **options: Any) -> Transport:
    """Open the link ``url`` names (see the module docs); ``options`` go to the backend.

    Raises :class:`UsageError` for an unknown scheme or a URL its backend cannot read (a
    ``ValueError`` it raises: ``?seed=abc``) and :class:`TransportError` when the link
    cannot be opened (no such port, permission, in use).
    """
    if not url:
        raise UsageError("no port given: a path such as /dev/ttyUSB0 or a transport URL")
    scheme = url_scheme(url)
    target: TransportFactory | str | None = _registered.get(scheme) or _BUILTIN.get(scheme)
    if target is None:
        target = _from_entry_points(scheme)
    if target is None:
        raise UsageError(f"unknown transport scheme {scheme!r} in {url!r}; "
                         f"known: {', '.join(schemes())}")
    factory = _resolve(target)
    try:
        return factory(url, **options)
    except UsageError:
        raise
    except ValueError as exc:  # a backend's own parsing of the URL's options
        raise UsageError(f"{url}: {exc}") from exc
