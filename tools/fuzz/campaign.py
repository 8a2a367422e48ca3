"""Stateful fuzzing campaigns: a hypothesis ``RuleBasedStateMachine`` per target kind.

Every example opens the target afresh (a new emulator in process, or the kept serial
port), then runs rules that send valid catalogue requests (extreme field values, split
across writes), broken frames (bad CRC, foreign address, lying length, truncation), waits,
bootloader page attacks, or Dynamixel instructions and register writes for the arm.  After
each step the oracles of :mod:`tools.fuzz.oracles` run; the first failure raises
:class:`FuzzFailure`, hypothesis shrinks the sequence, and :func:`run_campaign` returns
the minimal one as a :class:`~tools.fuzz.steps.Reproducer`.  :func:`replay` sends a saved
sequence again and tells whether the failure reproduces.
"""

from __future__ import annotations

import fnmatch
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

from host.errors import HostError
from protocol import strategies as pst
from protocol.catalogue import REQUEST, Message
from protocol.control_tables import RX64_TABLE, STEPPER_TABLE
from protocol.framing import encode_frame
from protocol.topology import SERVO_IDS, STEPPER_IDS
from tools.errors import FuzzFailure
from tools.fuzz.steps import Reproducer, Step
from tools.fuzz.targets import (
    FRAME_GAP_US,
    TARGETS,
    TargetKind,
    TargetLink,
    is_motion_frame,
    is_motion_packet,
)

#: Registers a campaign never writes: they make an arm node answer on another ID or baud
#: rate, which is the host's business, not a defect.
ARM_GUARDED_REGISTERS = ("id", "baud_rate")
#: Largest gap between the writes of one split frame (µs): under the decoders' gap.
MAX_SPLIT_GAP_US = FRAME_GAP_US // 2
#: Examples per round of a campaign with a time budget, each round with its own seed (the
#: budget is checked before each example, so a campaign overruns it by at most one).
SECONDS_ROUND: Final = 10
#: Mutations after which the target must stay silent and unchanged.
SILENT_MUTATIONS = ("bad_crc", "foreign_address")


@dataclass
class CampaignResult:
    """What a campaign found: ``examples`` run, and the minimal failing sequence if any.

    ``examples`` counts the sequences sent to the target (each on a target opened for it):
    hypothesis runs examples until ``max_examples`` of them are valid, and an example it
    draws and rejects before its first step opens no target and is not counted.  After a
    failure it also counts the replays hypothesis made while shrinking."""

    target: str
    seed: int
    examples: int
    seconds: float
    reproducer: Reproducer | None = None
    steps_sent: int = 0
    #: Wall time (s) and examples from the start until the first failing example, before
    #: any shrinking (None when nothing failed).
    first_failure_s: float | None = None
    examples_to_failure: int | None = None
    #: True when Ctrl-C (KeyboardInterrupt) ended the campaign before its budget.
    interrupted: bool = False
    #: Why the link to the target failed mid-campaign (the campaign ended there), or None.
    link_error: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def found(self) -> bool:
        return self.reproducer is not None


class LinkLost(BaseException):  # noqa: N818 - a signal through hypothesis, not an error
    """The link to the target failed in the middle of an example (its ``__cause__``, a
    :class:`~host.errors.HostError`: the port gone, the emulator behind it stopped).  A
    ``BaseException`` so hypothesis passes it straight up instead of shrinking it as a
    finding; :func:`run_campaign` ends the campaign with it."""


class BudgetSpent(BaseException):  # noqa: N818 - a signal through hypothesis, not an error
    """The campaign's ``seconds`` ran out before an example's first step; raised through
    hypothesis (a ``BaseException``) so the campaign stops there, within one example of
    its budget."""


class Checker:
    """Runs steps on a :class:`TargetLink` and applies every oracle after each."""

    def __init__(self, link: TargetLink) -> None:
        self.link = link
        self.motion_sent = False
        self.steps: list[Step] = []
        intro = link.introspection
        self._protected = intro.protected_digest() if intro else b""
        self._wire_protected = link.protected_over_wire()

    def run(self, step: Step) -> None:
        """Send ``step``, then check every oracle; raises :class:`FuzzFailure`."""
        self.steps.append(step)
        intro = self.link.introspection
        before = intro.state_digest() if intro and step.silent else b""
        try:
            self.link.write(step.chunks)
            heard = self.link.listen(step.wait_us / 1e6)
        except (HostError, FuzzFailure):
            raise
        except Exception as exc:  # an exception inside a firmware model, via the clock
            raise FuzzFailure(f"exception inside the target after {step.label}: "
                              f"{type(exc).__name__}: {exc}") from exc
        if step.motion:
            self.motion_sent = True
        if step.silent:
            answers = self.link.answers(heard, like=step.data)
            if answers:
                raise FuzzFailure(f"{step.label} drew an answer: {answers[0]!r}")
            if intro and intro.state_digest() != before:
                raise FuzzFailure(f"{step.label} changed the target's state")
        self.check()

    def check(self) -> None:
        """The oracles that hold after any step."""
        intro = self.link.introspection
        if intro is not None:
            if not self.motion_sent and (driven := intro.motors_driven()):
                raise FuzzFailure(f"motor driven without a motion command: {', '.join(driven)}")
            if intro.protected_digest() != self._protected:
                raise FuzzFailure("a bootloader page or the node identity changed")
            if problems := intro.invariant_violations():
                raise FuzzFailure("; ".join(problems))
        try:
            alive = self.link.alive()
        except HostError:
            raise  # the link itself failed: not the target's doing
        except Exception as exc:  # noqa: BLE001 - a firmware exception during the ping
            raise FuzzFailure(f"exception inside the target during the liveness ping: "
                              f"{type(exc).__name__}: {exc}") from exc
        if not alive:
            raise FuzzFailure(f"the {self.link.kind.name} no longer answers a ping within "
                              f"{self.link.kind.ping_deadline_s * 1e3:.0f} ms")

    def finish(self) -> None:
        """End of a sequence: the wire-level protected state is what it was."""
        if self.link.protected_over_wire() != self._wire_protected:
            raise FuzzFailure("bl.hash of the bootloader pages or identify changed")


def _label(frame: bytes, kind: TargetKind) -> str:
    from protocol.interpret import interpret
    from protocol.stream import StreamDecoder

    frames = StreamDecoder().feed(frame)
    if not frames:
        return "bytes"
    meaning = interpret(frames[0], kind.node)
    name = meaning.name or f"type 0x{frames[0].type:02x}"
    fields = "" if meaning.fields is None else f" {meaning.fields}"
    if len(fields) > 120:
        fields = fields[:117] + "..."
    return f"{name}{fields}"


def focus(kind: TargetKind, patterns: Sequence[str] | None) -> list[Message]:
    """The messages of ``kind`` whose names match one of the glob ``patterns`` (all
    when None); a pattern matching nothing is an error."""
    messages = kind.messages()
    if not patterns:
        return messages
    chosen = [m for m in messages if any(fnmatch.fnmatchcase(m.name, p) for p in patterns)]
    if not chosen:
        raise ValueError(f"no {kind.name} message matches {', '.join(patterns)}; "
                         f"choose among {', '.join(m.name for m in messages)}")
    return chosen


def machine_for(kind: TargetKind, opener: Callable[[], TargetLink],
                record: list[Checker], messages: Sequence[str] | None = None,
                on_failure: Callable[[], None] | None = None) -> type:
    """The RuleBasedStateMachine of ``kind``; each instance opens the target with
    ``opener`` and appends its :class:`Checker` to ``record``.  ``messages`` (glob
    patterns such as ``fmcb.param_*``) focuses the frames on those messages."""
    from hypothesis import strategies as st
    from hypothesis.stateful import RuleBasedStateMachine, precondition, rule

    dynamixel = kind.dynamixel
    if dynamixel:
        packets = st.one_of(
            pst.dynamixel_instructions(STEPPER_TABLE, STEPPER_IDS, ARM_GUARDED_REGISTERS),
            pst.dynamixel_instructions(RX64_TABLE, SERVO_IDS, ARM_GUARDED_REGISTERS))
        frames = packets
    else:
        frames = pst.request_frames(focus(kind, messages), kind.address)

    class Campaign(RuleBasedStateMachine):
        # The target is opened on the first step: an example hypothesis draws and then
        # rejects before any step (a rule whose precondition fails) costs no bring-up and
        # is not counted as an example.
        def __init__(self) -> None:
            super().__init__()
            self._checker: Checker | None = None
            self._lost = False  # the link failed: no end-of-sequence checks over it

        @property
        def checker(self) -> Checker:
            if self._checker is None:
                self._checker = Checker(opener())
                record.append(self._checker)
            return self._checker

        def teardown(self) -> None:
            if self._checker is None:
                return
            try:
                if not self._lost:
                    self._checker.finish()
            finally:
                self._checker.link.close()

        def _run(self, step: Step) -> None:
            try:
                self.checker.run(step)
            except FuzzFailure:
                if on_failure is not None:
                    on_failure()
                raise
            except HostError as exc:
                self._lost = True
                raise LinkLost(str(exc)) from exc

        @rule(data=st.data())
        def send_valid(self, data: Any) -> None:
            frame = data.draw(frames, label="frame")
            wire = kind.wrap(frame)
            split = data.draw(st.one_of(st.just([(wire, 0)]),
                                        pst.write_splits(wire, MAX_SPLIT_GAP_US)), label="split")
            motion = is_motion_packet(frame) if dynamixel else is_motion_frame(frame, kind.node)
            label = _dxl_label(frame) if dynamixel else _label(frame, kind)
            self._run(Step(label=label, chunks=tuple(split), motion=motion,
                           wait_us=kind.reply_wait_us))

        @rule(data=st.data())
        def send_broken(self, data: Any) -> None:
            frame = data.draw(frames, label="frame")
            if dynamixel:
                flip = data.draw(st.integers(0, 7), label="bit")
                broken = frame[:-1] + bytes([frame[-1] ^ (1 << flip)])
                self._run(Step(label=f"bad checksum {_dxl_label(frame)}",
                               chunks=((broken, 0),), silent=True,
                               wait_us=kind.reply_wait_us))
                return
            how = data.draw(st.sampled_from(pst.MUTATIONS), label="mutation")
            detail = data.draw(st.integers(0, 2**16), label="detail")
            broken = pst.mutate_frame(frame, how, detail, kind.neighbours)
            silent = how in SILENT_MUTATIONS
            self._run(Step(label=f"{how} {_label(frame, kind)}",
                           chunks=((kind.wrap(broken), 0),), silent=silent,
                           wait_us=kind.reply_wait_us))

        @rule(ms=st.integers(1, 3500 if kind.name == "bootloader" else 100))
        def wait(self, ms: int) -> None:
            self._run(Step(label=f"wait {ms} ms", chunks=(), wait_us=ms * 1000))

        @precondition(lambda self: kind.name == "bootloader")
        @rule(page=st.one_of(st.integers(0, 40), st.integers(1016, 1023), st.integers(0, 2**32 - 1)),
              data=st.binary(min_size=256, max_size=256), name=st.sampled_from(
                  ["bl.write_page", "bl.read_page", "bl.hash", "bl.activate", "bl.boot"]))
        def bootloader_command(self, page: int, data: bytes, name: str) -> None:
            from protocol.messages import CATALOGUE

            msg = CATALOGUE[name]
            fields: dict[str, Any] = {}
            if name == "bl.write_page":
                fields = {"page": page, "data": data}
            elif name == "bl.read_page":
                fields = {"page": page}
            elif name == "bl.hash":
                fields = {"start_page": page % 1024, "pages": 1 + page % 64}
            elif name == "bl.activate":
                fields = {"sha256": data[:32]}
            frame = encode_frame(kind.address, msg.type_id, msg.build(REQUEST, fields))
            self._run(Step(label=_label(frame, kind), chunks=((frame, 0),), wait_us=60_000))

    Campaign.__name__ = f"{kind.name.capitalize()}Campaign"
    Campaign.__qualname__ = Campaign.__name__
    return Campaign


def _dxl_label(packet: bytes) -> str:
    from protocol import dynamixel as dx

    try:
        p = dx.InstructionPacket.decode(packet)
    except Exception:  # noqa: BLE001
        return "dynamixel bytes"
    name = getattr(p.instruction, "name", f"0x{p.instruction:02x}")
    return f"dynamixel {name} id {p.id} params {p.params.hex()}"


def run_campaign(target: str, port: str | None = None, *, examples: int | None = 50,
                 seconds: float | None = None, seed: int = 0, steps: int = 12,
                 shared: dict[str, Any] | None = None,
                 messages: Sequence[str] | None = None, shrink: bool = True) -> CampaignResult:
    """Fuzz ``target`` on ``port`` (default: the emulator that has it) for ``examples``
    sequences of up to ``steps`` steps, or for ``seconds`` of wall time; ``messages``
    (glob patterns) focuses the campaign on some messages.  ``shrink=False`` stops at the
    first failing example and keeps it as found (no shrinking, no minimising: how soon a
    defect is found, without the cost of making its reproducer small)."""
    from hypothesis import HealthCheck, Phase, settings
    from hypothesis import seed as hypothesis_seed
    from hypothesis.stateful import run_state_machine_as_test

    kind = TARGETS[target]
    url = port or kind.url
    record: list[Checker] = []
    links: dict[str, Any] = shared if shared is not None else {}
    counter = [0]
    started = time.monotonic()
    result = CampaignResult(target, seed, 0, 0.0)
    # The first target is opened before hypothesis starts, so a port where nothing answers
    # is a TargetSilent here (a clear error), never a "finding" hypothesis shrinks.
    first = [TargetLink.open(kind, url, seed=seed, shared=links)]

    def opener() -> TargetLink:
        if (seconds is not None and counter[0] and result.first_failure_s is None
                and time.monotonic() - started >= seconds):
            raise BudgetSpent  # at least one example; never while a failure is shrunk
        counter[0] += 1
        return first.pop() if first else TargetLink.open(kind, url, seed=seed, shared=links)

    base = settings(stateful_step_count=steps, deadline=None, database=None, print_blob=False,
                    phases=[Phase.generate, Phase.shrink] if shrink else [Phase.generate],
                    suppress_health_check=list(HealthCheck))

    def noted() -> None:
        if result.first_failure_s is None:
            result.first_failure_s = time.monotonic() - started
            result.examples_to_failure = counter[0]

    # A time budget runs in rounds of a few examples, each round with its own seed.
    rounds = [(seed, examples or 50)] if seconds is None else (
        (seed * 100_003 + k, SECONDS_ROUND) for k in range(10**6))
    found: Reproducer | None = None
    try:
        for round_seed, batch in rounds:
            machine = machine_for(kind, opener, record, messages, noted)
            hypothesis_seed(round_seed)(machine)
            try:
                run_state_machine_as_test(machine, settings=settings(base, max_examples=batch))
            except FuzzFailure as exc:
                checker = record[-1]
                found = Reproducer(target=target, seed=round_seed, steps=list(checker.steps),
                                   failure=str(exc), port=url)
                result.reproducer = found
                if shrink and url.startswith("emu://"):
                    result.reproducer = minimise(found)
                break
            if seconds is None or time.monotonic() - started >= seconds:
                break
    except KeyboardInterrupt:
        # Ctrl-C: what ran so far is the result (a failure found keeps its sequence,
        # shrunk as far as it got).
        result.interrupted = True
    except LinkLost as lost:
        result.link_error = str(lost)
    except BudgetSpent:
        pass  # --seconds: the time ran out before the next example
    finally:
        for link in first:
            link.close()
    result.examples = counter[0]
    result.seconds = time.monotonic() - started
    result.steps_sent = sum(len(c.steps) for c in record)
    return result


def minimise(reproducer: Reproducer, port: str | None = None) -> Reproducer:
    """Drop every step whose removal keeps the same failure (replayed on fresh targets):
    hypothesis shrinks values well, while deleting a step from a stateful run can shift
    the draws of the steps after it, so a last greedy pass removes what is left."""
    steps = list(reproducer.steps)
    i = len(steps) - 1
    while i >= 0 and len(steps) > 1:
        trial = Reproducer(reproducer.target, reproducer.seed, steps[:i] + steps[i + 1:],
                           reproducer.failure, reproducer.port)
        if replay(trial, port) == reproducer.failure:
            steps = trial.steps
        i -= 1
    return Reproducer(reproducer.target, reproducer.seed, steps, reproducer.failure,
                      reproducer.port)


def replay(reproducer: Reproducer, port: str | None = None) -> str | None:
    """Send the reproducer's steps to ``port`` (default: its own, else the target's
    emulator) checking every oracle; the failure message if it reproduces, else None."""
    kind = TARGETS.get(reproducer.target)
    if kind is None:
        raise ValueError(f"the reproducer's target {reproducer.target!r} is not one of "
                         f"{', '.join(sorted(TARGETS))}")
    url = port or reproducer.port or kind.url
    link = TargetLink.open(kind, url, seed=reproducer.seed)
    checker = Checker(link)
    try:
        for step in reproducer.steps:
            checker.run(step)
        checker.finish()
    except FuzzFailure as exc:
        return str(exc)
    finally:
        link.close()
    return None
