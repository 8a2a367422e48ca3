"""Coverage-guided fuzzing in process of every stream decoder and firmware command handler.

    python -m tools.fuzz_inprocess TARGET [--runs N] [--engine atheris|hypothesis]
    python -m tools.fuzz_inprocess --list

Targets: ``stream`` (protocol.stream.StreamDecoder), ``dynamixel`` (DynamixelStreamDecoder),
``canlink`` (CanReassembler), ``manchester`` (decode_report_packed), and one per hand
node's command dispatch (``handler-palm``, ``handler-fmcb``, ``handler-f2``, ``handler-f3``,
``handler-bootloader``: ``HandNode.dispatch`` of a simulated node, every registered type).
Each input is split into chunks (and, for the handlers, a type id and payload) by its first
bytes; the properties: no exception but the package's own error tree, and what a decoder
yields is well formed.

With atheris (``pip install atheris``; libFuzzer's coverage feedback) the corpus under
``tests/fuzz_corpus/TARGET`` seeds the run and new inputs go to a temporary directory
(``--update-corpus`` writes them into the repository instead).  Without atheris the
hypothesis engine runs instead: random inputs from the corpus and ``st.binary``, with
``hypothesis.target`` steering toward inputs that complete more frames, and its example
database in the temporary directory; it ends with ``TARGET: N inputs, no failure``.
``--runs`` must be >= 1 (libFuzzer would take 0 or less as "run forever").
"""

from __future__ import annotations

import argparse
import functools
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, Final

from protocol.topology import HAND_BOARDS
from tools.cli.numeric import number_above, read_negative_numbers
from tools.cli.output import guard_output
from tools.errors import FuzzPropertyError

#: ``--runs``: a number of inputs >= 1.
_RUNS = number_above(1, int, inclusive=True, what="a number of runs",
                     note=" (libFuzzer takes 0 or less as run forever; stop such a run "
                     "with Ctrl-C)")

#: The repository's small seed corpus, one folder per target.
CORPUS_ROOT: Final = Path(__file__).resolve().parent.parent / "tests" / "fuzz_corpus"
#: The hand boards' message handlers, and the bootloader's (every hand board runs it).
HANDLER_BOARDS: Final = (*(b.app for b in HAND_BOARDS), "bootloader")


def _chunks(data: bytes) -> list[bytes]:
    """The input cut where its first byte says (a cut every 1 + b % 16 bytes)."""
    if not data:
        return []
    step = 1 + data[0] % 16
    body = data[1:]
    return [body[i:i + step] for i in range(0, len(body), step)]


def fuzz_stream(data: bytes) -> int:
    """StreamDecoder: never raises; every frame re-encodes to bytes the input contains."""
    from protocol.framing import encode_frame
    from protocol.stream import StreamDecoder

    decoder = StreamDecoder()
    frames = []
    for i, chunk in enumerate(_chunks(data)):
        frames += decoder.feed(chunk, i * 0.001)
    frames += decoder.flush()
    for f in frames:
        if encode_frame(f.address, f.type, f.payload) not in data[1:]:
            raise FuzzPropertyError(f"decoded {f!r}, which the input does not contain")
    return len(frames)


def fuzz_dynamixel(data: bytes) -> int:
    """DynamixelStreamDecoder (auto direction): never raises; packets re-encode."""
    from protocol.dynamixel import DynamixelStreamDecoder

    decoder = DynamixelStreamDecoder("auto")
    packets = []
    for chunk in _chunks(data):
        packets += decoder.feed(chunk)
    for p in packets:
        if p.packet.encode() != p.raw:
            raise FuzzPropertyError(f"packet {p!r} does not re-encode to its bytes")
    return len(packets)


def fuzz_canlink(data: bytes) -> int:
    """CanReassembler: CAN frames of ≤ 8 bytes on a few identifiers; never raises."""
    from protocol.canlink import TO_HOST_BASE, TO_NODE_BASE, CanReassembler

    reassembler = CanReassembler()
    ids = (TO_NODE_BASE + 0x0A, TO_HOST_BASE + 0x0A, TO_HOST_BASE + 0x01, 0x7FF)
    n = 0
    for i, chunk in enumerate(_chunks(data)):
        n += len(reassembler.feed(ids[chunk[0] % 4] if chunk else ids[0], chunk[:8], i * 1e-4))
    return n


def fuzz_manchester(data: bytes) -> int:
    """Manchester decode of packed chips: only ManchesterError, and a report that counts
    no more characters than the chips can hold."""
    from protocol.errors import ManchesterError
    from protocol.manchester import chips_per_character, decode_report_packed

    try:
        report = decode_report_packed(data)
    except ManchesterError:
        return 0
    if len(report.data) > len(data) * 8 // chips_per_character():
        raise FuzzPropertyError("more characters decoded than the chips hold")
    return len(report.data)


_NODES: dict[str, Any] = {}


def _node(board: str) -> Any:
    """A simulated node of ``board`` running its program (``bootloader``: an fmcb held in
    its bootloader), made once."""
    if board not in _NODES:
        from firmware_py.scheduler import Scheduler
        from firmware_py.sim.boards import make_node
        from protocol.topology import BoardType
        from protocol.topology import board as board_row

        scheduler = Scheduler()
        kind = BoardType.FMCB if board == "bootloader" else board_row(board).board_type
        mcu = make_node(scheduler, kind, installed=board != "bootloader")
        mcu.power_on()
        scheduler.run_for(3_500_000)
        _NODES[board] = (scheduler, mcu)
    return _NODES[board]


def fuzz_handler(board: str, data: bytes) -> int:
    """One request to a node's dispatch: byte 0 picks a registered type id, the rest is
    the payload; only the package's errors are caught by dispatch, so any exception
    escaping is a defect.  Replies must be frames the catalogue parses."""
    from firmware_py.hal import Uart
    from protocol.catalogue import REPLY
    from protocol.framing import Frame
    from protocol.messages import CATALOGUE

    scheduler, mcu = _node(board)
    program = mcu.program
    types = sorted(program._routes)
    if not data or not types:
        return 0
    msg_type = types[data[0] % len(types)]
    payload = data[1:]
    sent: list[tuple[bytes | None, int]] = []
    uart: Uart = next(iter(mcu.hal.uarts.values()))
    frame = Frame(program.address, msg_type, payload)
    program.dispatch(msg_type, payload, frame, uart, lambda p, s: sent.append((p, s)))
    scheduler.run_for(2_000)
    msg = CATALOGUE.lookup(program.node_kind, msg_type)
    for reply, _status in sent:
        if reply is not None and msg is not None and msg.reply is not None:
            msg.parse(REPLY, reply)  # raises PayloadError on a malformed reply
    return len(sent)


def targets() -> dict[str, Callable[[bytes], int]]:
    """Every in-process target by name."""
    out: dict[str, Callable[[bytes], int]] = {
        "stream": fuzz_stream, "dynamixel": fuzz_dynamixel, "canlink": fuzz_canlink,
        "manchester": fuzz_manchester}
    for board in HANDLER_BOARDS:
        out[f"handler-{board}"] = functools.partial(fuzz_handler, board)
    return out


def run_one(target: str, data: bytes) -> int:
    """Run one input; raises the first property failure or unexpected exception."""
    from protocol.errors import ProtocolError

    try:
        return targets()[target](data)
    except ProtocolError as exc:
        if target.startswith("handler-"):
            raise FuzzPropertyError(f"{target}: {type(exc).__name__}: {exc}") from exc
        raise


def corpus(target: str) -> list[bytes]:
    """The seed inputs kept in the repository for ``target``."""
    folder = CORPUS_ROOT / target
    return [p.read_bytes() for p in sorted(folder.glob("*")) if p.is_file()] \
        if folder.is_dir() else []


def run_atheris(target: str, runs: int, update_corpus: bool) -> int:
    import atheris  # type: ignore[import-not-found]

    fn = targets()[target]
    with atheris.instrument_imports():
        import protocol.canlink  # noqa: F401
        import protocol.dynamixel  # noqa: F401
        import protocol.manchester  # noqa: F401
        import protocol.stream  # noqa: F401
    if target.startswith("handler-"):
        _node(target.split("-", 1)[1])
        atheris.instrument_all()
    seeds = CORPUS_ROOT / target
    seeds.mkdir(parents=True, exist_ok=True)
    work = seeds if update_corpus else Path(tempfile.mkdtemp(prefix=f"fuzz-{target}-"))
    argv = [sys.argv[0], f"-runs={runs}", "-max_len=600", str(work)]
    if not update_corpus:
        argv.append(str(seeds))

    def one(data: bytes) -> None:
        fn(data)

    atheris.Setup(argv, one)
    atheris.Fuzz()
    return 0


def run_hypothesis(target: str, runs: int) -> int:
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st
    from hypothesis import target as steer
    from hypothesis.database import DirectoryBasedExampleDatabase

    seeds = corpus(target)
    inputs = st.one_of(st.sampled_from(seeds), st.binary(max_size=600)) if seeds \
        else st.binary(max_size=600)
    database = DirectoryBasedExampleDatabase(
        str(Path(tempfile.gettempdir()) / "fuzz-hypothesis-db" / target))

    tried = [0]

    @settings(max_examples=runs, deadline=None, database=database,
              suppress_health_check=list(HealthCheck))
    @given(inputs)
    def check(data: bytes) -> None:
        tried[0] += 1
        steer(float(run_one(target, data)), label="items decoded")

    check()
    print(f"{target}: {tried[0]} inputs, no failure (hypothesis engine)")
    return 0


def engine_available() -> str:
    """``atheris`` when it imports, else ``hypothesis``."""
    try:
        import atheris  # type: ignore[import-not-found]  # noqa: F401
    except ImportError:
        return "hypothesis"
    return "atheris"


@guard_output("fuzz_inprocess")
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.fuzz_inprocess",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("target", nargs="?", choices=sorted(targets()))
    parser.add_argument("--runs", type=_RUNS, default=10_000,
                        help="inputs to try (default 10000)")
    parser.add_argument("--engine", choices=("atheris", "hypothesis"))
    parser.add_argument("--update-corpus", action="store_true",
                        help="atheris: write new inputs into tests/fuzz_corpus/TARGET")
    parser.add_argument("--list", action="store_true", help="list the targets")
    args = read_negative_numbers(parser).parse_args(argv)
    if args.list or args.target is None:
        print("\n".join(sorted(targets())))
        return 0
    engine = args.engine or engine_available()
    if engine == "atheris":
        return run_atheris(args.target, args.runs, args.update_corpus)
    return run_hypothesis(args.target, args.runs)


if __name__ == "__main__":
    sys.exit(main())
