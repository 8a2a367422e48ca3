"""What every recorder shares: topics, sinks, and an MCAP file written as it goes.

A recorder (:class:`host.hand.recording.HandRecorder`, :class:`host.arm.recording.ArmRecorder`)
is a :class:`Recording`: it declares its :class:`Topic` s once and calls :meth:`Recording.log`
with each message's bytes and its time on the link's clock; the recording stamps it with the
wall clock and hands it to every :class:`Sink`.  :class:`McapFile` is the sink that writes
the MCAP file; a second sink (a live view, a network feed) is any object with the three
methods of :class:`Sink`, added with :meth:`Recording.add_sink`.

Times.  An MCAP message's ``log_time`` is the wall clock (ns since 1970-01-01 UTC) when the
host logged it, so a viewer shows when the recording happened; its ``publish_time`` is the
link's clock (ns: the simulation clock with the in-process emulator, a monotonic clock on a
serial port), and every JSON message carries the same as its field ``t`` (s).

Written as it goes.  :class:`McapFile` closes the chunk in progress and writes it to the file
at least every :data:`FLUSH_INTERVAL_S` of wall time (a thread does it when no message comes),
so a process killed with ``kill -9`` loses at most the last second (that thread takes the
real-time scheduling of the thread that opens the file, :func:`~host.scheduling.adopt`: it
holds the file's lock while it writes, and a real-time control loop logging through the
same lock must not wait behind it for a normal process's slice); such a file has no summary
section and ``handbus decode`` reads it up to its cut.  A write that fails (a full disk) stops
the file where it is: nothing more is written, what was written stays, and the recorder's
next :meth:`Recording.check` raises :class:`~host.errors.RecordingError` saying why.  A sink
never raises from :meth:`Sink.write`: the recorders' taps run inside the links' own
send and receive paths.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Final, Protocol

from mcap.writer import CompressionType, Writer

from host.errors import RecordingError
from host.scheduling import Scheduling, adopt, current

#: The longest wall time (s) a logged message waits in memory before its chunk is written.
FLUSH_INTERVAL_S: Final = 0.5
#: A chunk is also written once it holds this many bytes (uncompressed).
CHUNK_BYTES: Final = 256 * 1024
#: Message encoding and schema encoding of the JSON topics.
JSON_ENCODING: Final = "json"
JSON_SCHEMA_ENCODING: Final = "jsonschema"
#: Name of the MCAP metadata record saying what was recorded (:func:`source_metadata`).
SOURCE_METADATA: Final = "source"


@dataclass(frozen=True)
class Topic:
    """One channel of a recording: ``name`` (``/hand/state``), message ``encoding``
    (``json``, ``hand-frame``, ``application/octet-stream``), and for JSON topics the
    ``schema`` (a JSON Schema, its fields' units in their descriptions) named
    ``schema_name``."""

    name: str
    encoding: str
    schema_name: str = ""
    schema: Mapping[str, Any] | None = None


class Sink(Protocol):
    """Where a recording's messages go.  ``write`` must not raise (keep the error and say
    it from ``close`` or an ``error`` attribute): it runs inside the links' taps."""

    def add_topic(self, topic: Topic) -> None:
        """Declare ``topic`` before its first message."""

    def write(self, topic: Topic, log_time_ns: int, link_time_s: float, data: bytes) -> None:
        """One message: wall-clock ``log_time_ns`` (ns since 1970), ``link_time_s`` (s, the
        link's clock), ``data`` (JSON text or raw bytes, by the topic's encoding)."""

    def close(self) -> None:
        """No more messages."""


def source_metadata(link: str, url: str, now_s: float, prologue: str,
                    earlier: int | None, others: bool = False) -> dict[str, str]:
    """The :data:`SOURCE_METADATA` record of a recorder on host link ``link`` (``arm``,
    ``palm``, ``finger``) opened as ``url``, attached at ``now_s`` (s, the link's clock),
    having written the link's first messages (:mod:`host.recording.prologue`: ``complete``
    when every message since the link opened is in the file, else ``partial``) and
    ``earlier`` sends of other programs on the same link before it opened (their count, when
    the transport knows them: :meth:`host.transports.base.Transport.sent_before`; else
    ``unknown``), and whether what other programs sent on it while it recorded is in the
    file (``others``: ``kept`` when the transport could tell,
    :meth:`~host.transports.base.Transport.watch_others`; else ``unknown``).

    What the emulator that answered was (configuration, seed, sensors, scene) is in an
    ``emu://`` URL's path and options; a serial port or a pty says nothing of it, and a
    replay says what it assumes instead."""
    return {"link": link, "url": url, "start_t": repr(float(now_s)), "prologue": prologue,
            "earlier": "unknown" if earlier is None else str(earlier),
            "others": "kept" if others else "unknown"}


def link_ns(t: float) -> int:
    """The link's clock ``t`` (s) as MCAP nanoseconds (never negative)."""
    return max(0, int(round(t * 1e9)))


class McapFile:
    """An MCAP file at ``path``, written as it goes (a :class:`Sink`).  Opening it creates
    (or empties) the file: :class:`RecordingError` if it cannot.  ``error`` is the
    ``OSError`` that stopped the writing, if one did; ``messages`` counts the messages
    taken, ``saved`` those in chunks written to the file."""

    def __init__(self, path: str | Path, *, library: str,
                 flush_interval_s: float | None = None,
                 metadata: Mapping[str, Mapping[str, str]] | None = None) -> None:
        self.path = Path(path)
        self.error: OSError | None = None
        self.messages = 0
        self.saved = 0
        self._interval = FLUSH_INTERVAL_S if flush_interval_s is None else flush_interval_s
        self._lock = threading.Lock()
        self._channels: dict[str, int] = {}
        self._sequence: dict[str, int] = {}
        self._unflushed = False
        self._last_flush = time.monotonic()
        self._closed = False
        try:
            self._stream: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        except OSError as exc:
            raise RecordingError(f"cannot write the recording to {self.path}: "
                                 f"{exc.strerror or exc}") from exc
        self._writer = Writer(self._stream, chunk_size=CHUNK_BYTES,
                              compression=CompressionType.ZSTD)
        try:
            self._writer.start(profile="", library=library)
            for name, record in (metadata or {}).items():
                self._writer.add_metadata(name, dict(record))
            self._stream.flush()
        except OSError as exc:
            self._fail(exc)
        self._stop = threading.Event()
        self._opener: Scheduling = current()
        #: the scheduling the flushing thread got (once it runs)
        self.flusher_scheduling: Scheduling | None = None
        self._flusher = threading.Thread(target=self._flush_loop, daemon=True,
                                         name=f"mcap-flush {self.path.name}")
        self._flusher.start()

    # ------------------------------------------------------------------ the Sink
    def add_topic(self, topic: Topic) -> None:
        with self._lock:
            if self.error is not None or topic.name in self._channels:
                return
            schema_id = 0
            if topic.schema is not None:
                schema_id = self._writer.register_schema(
                    topic.schema_name or topic.name, JSON_SCHEMA_ENCODING,
                    json.dumps(topic.schema).encode())
            self._channels[topic.name] = self._writer.register_channel(
                topic.name, topic.encoding, schema_id)
            self._sequence[topic.name] = 0

    def write(self, topic: Topic, log_time_ns: int, link_time_s: float, data: bytes) -> None:
        with self._lock:
            if self.error is not None or self._closed:
                return
            seq = self._sequence[topic.name]
            self._sequence[topic.name] = seq + 1
            try:
                before = self._stream.tell()
                self._writer.add_message(self._channels[topic.name], log_time_ns, data,
                                         link_ns(link_time_s), sequence=seq)
                self.messages += 1
                self._unflushed = True
                if self._stream.tell() != before:
                    # The writer closed a full chunk (CHUNK_BYTES), this message in it: on
                    # disk once the stream is flushed, so a later failure keeps it counted.
                    self._flush()
                elif time.monotonic() - self._last_flush >= self._interval:
                    self._flush()
            except OSError as exc:
                self._fail(exc)

    def close(self) -> None:
        """Finish the file (summary and footer) and close it; after a failed write, close
        it as it is (idempotent)."""
        self._stop.set()
        if self._flusher is not threading.current_thread():
            self._flusher.join()
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                if self.error is None:
                    self._writer.finish()
                    self._stream.flush()
                    self.saved = self.messages
            except OSError as exc:
                self._fail(exc)
            try:
                self._stream.close()
            except OSError as exc:
                if self.error is None:
                    self.error = exc

    # ------------------------------------------------------------------ internals
    def _flush(self) -> None:
        """Write the chunk in progress (caller holds the lock; raises OSError)."""
        self._writer.flush()
        self.saved = self.messages
        self._unflushed = False
        self._last_flush = time.monotonic()

    def _fail(self, exc: OSError) -> None:
        if self.error is None:
            self.error = exc

    def _flush_loop(self) -> None:
        self.flusher_scheduling = adopt(self._opener)
        while not self._stop.wait(self._interval / 2):
            with self._lock:
                if (self._unflushed and self.error is None and not self._closed
                        and time.monotonic() - self._last_flush >= self._interval):
                    try:
                        self._flush()
                    except OSError as exc:
                        self._fail(exc)


class Recording:
    """A recorder's fan-out: ``topics`` declared to every sink, each :meth:`log` call given
    to every sink with the wall clock.  ``path`` (or None: no file) is the MCAP file
    (:class:`McapFile`, :attr:`file`); ``sinks`` are more."""

    def __init__(self, path: str | Path | None, topics: Sequence[Topic], *, library: str,
                 sinks: Sequence[Sink] = (),
                 metadata: Mapping[str, Mapping[str, str]] | None = None) -> None:
        self.topics = tuple(topics)
        self.file = None if path is None else McapFile(path, library=library,
                                                       metadata=metadata)
        self.sinks: list[Sink] = []
        for sink in ([self.file] if self.file is not None else []) + list(sinks):
            self.add_sink(sink)
        self._open = True

    @property
    def path(self) -> Path | None:
        """The MCAP file's path (None without one)."""
        return None if self.file is None else self.file.path

    def add_sink(self, sink: Sink) -> None:
        """Give ``sink`` the topics and, from now on, every message."""
        for topic in self.topics:
            sink.add_topic(topic)
        self.sinks.append(sink)

    def log(self, topic: Topic, link_time_s: float, data: bytes) -> None:
        """One message of ``topic`` at ``link_time_s`` (s, the link's clock), stamped with
        the wall clock now."""
        if not self._open:
            return
        now = time.time_ns()
        for sink in self.sinks:
            sink.write(topic, now, link_time_s, data)

    def log_json(self, topic: Topic, link_time_s: float, value: Any) -> None:
        """:meth:`log` of ``value`` as JSON text."""
        self.log(topic, link_time_s, json.dumps(value).encode())

    @property
    def error(self) -> OSError | None:
        """Why the file stopped being written, or None."""
        return None if self.file is None else self.file.error

    def check(self) -> None:
        """:class:`RecordingError` if the file could not be written (a full disk): the
        recording stopped there, and what was written before stays."""
        if (exc := self.error) is not None:
            saved = 0 if self.file is None else self.file.saved
            raise RecordingError(f"cannot write the recording to {self.path}: "
                                 f"{exc.strerror or exc}; it stopped there, keeping the "
                                 f"{saved} messages written before")

    def close_sinks(self) -> None:
        """Close every sink (idempotent)."""
        if not self._open:
            return
        self._open = False
        for sink in self.sinks:
            sink.close()
