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

Each backend is a :class:`Transport` subclass that declares its own URL schemes and, for
each, the kind of link it is (:class:`LinkKind`: a name, the default link budget of a
session on it, whether arrival times are the wire's own), as python-can's interfaces declare
themselves: a class that declares ``schemes`` is registered when its module is imported.
The built-in backends are the modules of :mod:`host.transports`, imported when a scheme is
first looked up (python-can itself only when a ``can://`` link opens).  Other packages add
schemes with such a class, with :func:`register_transport`, or through the
``lowcost_hand.transports`` entry-point group (the scheme's name → the class or a factory).
"""

from __future__ import annotations

import importlib
import pkgutil
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib import metadata
from typing import Any, ClassVar, Final
from urllib.parse import parse_qsl, urlsplit

from host.errors import TransportError, UsageError

#: Entry-point group through which other packages register transport schemes.
ENTRY_POINT_GROUP: Final = "lowcost_hand.transports"
#: Default serial rate of hand links (palm USB port, loose-finger cable), bit/s.
HAND_SERIAL_BAUD: Final = 2_000_000


@dataclass(frozen=True)
class LinkKind:
    """What kind of link a URL scheme opens, for a session's timing defaults.

    ``name``: ``"serial"``, ``"can"``, ``"network"``, ``"loop"``, ``"in-process"`` …;
    ``budget_s``: the default link budget (s) of a hand session on it (the link both ways
    and the first node's turnaround; None: the session's own default); ``exact_timing``:
    bytes arrive at their wire times (the simulation clock, ``loop://``), so a stream
    decoder's inter-frame gap holds as it is and runs are repeatable.
    """

    name: str
    budget_s: float | None = None
    exact_timing: bool = False


#: A scheme whose backend declares no kind (a factory registered by another package).
OTHER_LINK: Final = LinkKind("other")


class Transport(ABC):
    """Bytes to and from one link.  A context manager; :meth:`close` is idempotent.

    :meth:`send` takes whole frames (a CAN backend cuts each into CAN frames);
    :meth:`recv` returns the bytes that arrived, or ``b""`` when ``timeout`` (seconds on
    :meth:`now`'s clock) passed without any.

    A backend declares the URL schemes it opens in ``schemes`` (scheme → :class:`LinkKind`)
    and opens one in :meth:`from_url`; declaring ``schemes`` registers the class.
    """

    #: The URL schemes this backend opens, each with the kind of link it is.
    schemes: ClassVar[Mapping[str, LinkKind]] = {}

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "schemes" in cls.__dict__:  # declared by this class, not inherited
            for scheme in cls.schemes:
                _declared[scheme.lower()] = cls

    @classmethod
    def from_url(cls, url: str, **options: Any) -> Transport:
        """Open the link ``url`` names (a backend's own URL syntax and ``?options``)."""
        raise UsageError(f"{url}: {cls.__name__} cannot be opened from a URL")

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

    def recv_timed(self, timeout: float | None = 0.0) -> list[tuple[float, bytes]]:
        """:meth:`recv`, as ``(t, bytes)`` chunks stamped with the link's clock when they
        arrived (s): when they were read, on a port (all a host can know); their exact
        arrival on the in-process emulator's clock, where a host busy with another link
        reads them later.  Empty when nothing arrived."""
        self._require_open()
        if timeout is not None and timeout < 0:
            timeout = 0.0
        return self._recv_timed(timeout)

    def now(self) -> float:
        """The link's clock (s): wall-clock monotonic time, or the simulation's."""
        return time.monotonic()

    def sent_before(self) -> list[tuple[float, bytes]] | None:
        """What earlier transports sent on this same link before this one opened, as
        ``(t, bytes)`` on this transport's clock, when the transport can know it (the
        in-process emulator keeps its links' host input); None when it cannot (a serial
        port: the robot does not say what it was sent).  A recorder writes it, so a replay
        starts from the robot the recording found."""
        return None

    def watch_others(self) -> bool:
        """Keep, from now on, what other transports send on this same link while this one
        is open (:meth:`take_others` hands it over), when the transport can know it (the
        in-process emulator, where two programs can share a link); False when it cannot
        (a serial port holds its link alone, or says nothing of who else is on it)."""
        return False

    def take_others(self) -> list[tuple[float, bytes]]:
        """What other transports sent on this link since :meth:`watch_others` or the last
        call (``(t, bytes)`` on this transport's clock, in order); empty when not watched.
        A recorder writes it, so a replay also sends what another program (a flasher
        beside the hand's own link) did to the robot meanwhile."""
        return []

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

    def _recv_timed(self, timeout: float | None) -> list[tuple[float, bytes]]:
        data = self._recv(timeout)
        return [(self.now(), data)] if data else []

    def _reopen(self) -> None:
        raise TransportError(f"{self.url}: this transport cannot be reopened")


TransportFactory = Callable[..., Transport]

#: Scheme → the backend class that declared it (filled as backend modules are imported).
_declared: dict[str, type[Transport]] = {}
#: Scheme → a factory (or ``"module:attr"``) registered with :func:`register_transport`.
_registered: dict[str, TransportFactory | str] = {}
#: The package whose modules are the built-in backends.
_BUILTIN_PACKAGE: Final = "host.transports"
_builtins_loaded = False


def _load_builtins() -> None:
    """Import every module of :mod:`host.transports` (each declares its backend)."""
    global _builtins_loaded
    if _builtins_loaded:
        return
    package = importlib.import_module(_BUILTIN_PACKAGE)
    for module in pkgutil.iter_modules(package.__path__):
        importlib.import_module(f"{_BUILTIN_PACKAGE}.{module.name}")
    _builtins_loaded = True


def register_transport(scheme: str | type[Transport],
                       factory: TransportFactory | str | None = None) -> None:
    """Make ``scheme://…`` URLs open with ``factory`` (a callable, or ``"module:attr"``
    imported on first use); or, given a :class:`Transport` subclass, every scheme it
    declares (as its import already did)."""
    if isinstance(scheme, type):
        for name in scheme.schemes:
            _declared[name.lower()] = scheme
        return
    if factory is None:
        raise TypeError("register_transport(scheme, factory): no factory given")
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


def _backend(scheme: str) -> TransportFactory | None:
    """What opens ``scheme``: a registered factory, a declaring class's ``from_url``, or an
    entry point's (a class or a factory)."""
    target = _registered.get(scheme)
    if target is not None:
        found: object = _resolve(target)
    else:
        if scheme not in _declared:
            _load_builtins()
        found = _declared[scheme] if scheme in _declared else _from_entry_points(scheme)
    if isinstance(found, type) and issubclass(found, Transport):
        return found.from_url
    return found if callable(found) else None


def _declaring_class(factory: TransportFactory) -> type[Transport] | None:
    """The backend class behind ``factory``: the class itself or its bound ``from_url``."""
    owner = factory if isinstance(factory, type) else getattr(factory, "__self__", None)
    return owner if isinstance(owner, type) and issubclass(owner, Transport) else None


def url_scheme(url: str) -> str:
    """The scheme of a transport URL; a bare path (no ``://``) is ``serial``."""
    if "://" not in url:
        return "serial"
    return url.split("://", 1)[0].lower()


def link_of(url: str) -> LinkKind:
    """The kind of link ``url`` opens, as its backend declares it (:data:`OTHER_LINK` for an
    unknown scheme or a backend that declares none); imports the backend if need be."""
    scheme = url_scheme(url)
    factory = _backend(scheme)
    owner = None if factory is None else _declaring_class(factory)
    return OTHER_LINK if owner is None else owner.schemes.get(scheme, OTHER_LINK)


def declared_links() -> dict[str, LinkKind]:
    """Every link kind a backend declares, by name: the built-in backends', and those of
    the entry-point group's (each loaded)."""
    _load_builtins()
    for entry in metadata.entry_points(group=ENTRY_POINT_GROUP):
        entry.load()  # a backend class registers itself as its module is imported
    return {kind.name: kind for cls in _declared.values() for kind in cls.schemes.values()}


def link_kind(url: str) -> str:
    """``"serial"`` (a device or pty: USB adapters buffer up to their latency timer, 16 ms
    by default), ``"can"``, ``"network"`` (``socket://``, ``rfc2217://``), ``"loop"``,
    ``"in-process"`` (``emu://``: the simulation clock, exact wire times), or ``"other"``
    for a scheme whose backend declares no kind: :func:`link_of`'s name."""
    return link_of(url).name


def url_options(url: str) -> dict[str, str]:
    """The ``?key=value`` options of a URL or of a path (``/dev/ttyUSB0?baud=1000000``)."""
    if "://" in url:
        return dict(parse_qsl(urlsplit(url).query))
    return dict(parse_qsl(url.split("?", 1)[1])) if "?" in url else {}


def schemes() -> list[str]:
    """Every scheme :func:`open_transport` knows now (built-in, registered, entry points)."""
    _load_builtins()
    found = set(_declared) | set(_registered)
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
    backend = _backend(scheme)
    if backend is None:
        raise UsageError(f"unknown transport scheme {scheme!r} in {url!r}; "
                         f"known: {', '.join(schemes())}")
    try:
        return backend(url, **options)
    except UsageError:
        raise
    except ValueError as exc:  # a backend's own parsing of the URL's options
        raise UsageError(f"{url}: {exc}") from exc
