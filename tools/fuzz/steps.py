"""What a fuzzing campaign sends, as data: steps and the reproducer file that keeps them.

A :class:`Step` is bytes written to the target link in chunks (each after a gap, µs), with
what the campaign knows of it: a label people read, whether the target must stay silent
and unchanged (a bad CRC, a foreign address), and whether it is a valid motion command.
A :class:`Reproducer` is the target kind, the seed, the sequence of steps and the failure;
it is saved as JSON and replayed by ``hil-fuzz replay``.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

#: Reproducer file format version.
FORMAT: int = 1


@dataclass(frozen=True)
class Step:
    """One action on the link: ``chunks`` are (bytes, gap before them in µs); ``wait_us``
    is how long to listen afterwards (µs) for a reply."""

    label: str
    chunks: tuple[tuple[bytes, int], ...]
    silent: bool = False  #: must cause no reply and no observable change
    motion: bool = False  #: a valid command that may move a motor
    wait_us: int = 20_000

    @property
    def data(self) -> bytes:
        """All the bytes of the step, joined."""
        return b"".join(chunk for chunk, _gap in self.chunks)

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict (bytes as hex)."""
        out = asdict(self)
        out["chunks"] = [[chunk.hex(), gap] for chunk, gap in self.chunks]
        return out

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Step:
        """The inverse of :meth:`to_json`."""
        chunks = tuple((bytes.fromhex(h), int(g)) for h, g in data["chunks"])
        return cls(label=str(data["label"]), chunks=chunks, silent=bool(data.get("silent")),
                   motion=bool(data.get("motion")), wait_us=int(data.get("wait_us", 20_000)))

    def __str__(self) -> str:
        split = f" in {len(self.chunks)} writes" if len(self.chunks) > 1 else ""
        return f"{self.label}: {self.data.hex()}{split}"


@dataclass
class Reproducer:
    """A failing sequence: target kind, seed, steps and the failure they cause."""

    target: str
    seed: int
    steps: list[Step]
    failure: str
    port: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"format": FORMAT, "target": self.target, "seed": self.seed, "port": self.port,
                "failure": self.failure, "steps": [s.to_json() for s in self.steps],
                **self.extra}

    def save(self, directory: str | Path) -> Path:
        """Write ``<target>-seed<seed>.json`` under ``directory``; returns the path."""
        out = Path(directory)
        out.mkdir(parents=True, exist_ok=True)
        path = out / f"{self.target}-seed{self.seed}.json"
        path.write_text(json.dumps(self.to_json(), indent=1) + "\n")
        return path

    @classmethod
    def load(cls, path: str | Path) -> Reproducer:
        """The reproducer saved in ``path``; ``ValueError`` (saying what is wrong) if the
        file is not JSON or not a reproducer (``OSError`` if it cannot be read)."""
        try:
            data = json.loads(Path(path).read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ValueError(f"not JSON: {exc}") from None
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise ValueError(f"not a reproducer of format {FORMAT}")
        try:
            return cls(target=data["target"], seed=int(data["seed"]),
                       steps=[Step.from_json(s) for s in data["steps"]],
                       failure=str(data.get("failure", "")), port=str(data.get("port", "")))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ValueError(f"a reproducer with a missing or malformed key: "
                             f"{type(exc).__name__}: {exc}") from None
