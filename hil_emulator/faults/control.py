"""The fault control channel: a JSON-lines unix socket for a process outside the emulator.

``hil-emulator --link-dir DIR`` listens on ``DIR/control`` (``--control PATH`` elsewhere).
Each line a client writes is one JSON request; the emulator answers each with one line:

=================================================================  ==========================
request                                                            answer
=================================================================  ==========================
``{"op": "inject", "fault": NAME, "params": {...}, "at_s": 0,``     ``{"ok": true, "id": N,``
``"duration_s": null, "label": null}``                              ``"t_us": ...}``
``{"op": "clear", "id": N}``                                        ``{"ok": true}``
``{"op": "clear_all"}``                                             ``{"ok": true}``
``{"op": "active"}``                                                ``{"ok": true, "ids": [...]}``
``{"op": "timeline"}``                                              ``{"ok": true, "events": [...]}``
``{"op": "list"}``                                                  ``{"ok": true, "faults": [...]}``
``{"op": "status"}``                                                ``{"ok": true, "t_us": ...,``
                                                                   ``"max_ms": ..., ...}``
``{"op": "truth"}``                                                 ``{"ok": true, "t_us": ...,``
                                                                   ``"arm": {...} or null,``
                                                                   ``"hand": {...} or null}``
=================================================================  ==========================

``status`` is the simulation clock (``t_us``) with the real-time loop's lateness figures
(:meth:`~hil_emulator.pacing.Pacer.lateness_stats`: delivery lateness in ms,
``late_episodes``, ``slipped_s``): a test over the wire waits on the simulation clock and
takes its wall-clock margins from what the emulator reports, not from an idle machine.

``truth`` is what the wire cannot tell a bench over the ports: the arm plant's ground truth
(``joints`` J1..J7 and ``velocities`` in rad and rad/s, model coordinates; ``deflections`` of
the J1..J4 elastic elements in rad) and each arm node's ``torque_enable``,
``status_flags`` (stepper nodes; 0 on the RX-64s) and ``alarms`` (the Dynamixel error bits
it would report), keyed by bus ID; ``arm`` is null without an arm or a plant.  ``hand``
has each finger's fmcb (``fingers``, in finger order; null where it runs no application):
its RAM ``joint_limits`` (rad, ``[[lower, upper]]`` of J0..J2) and ``limit_lease`` (True
while widened limits are on lease, :mod:`firmware_py.limit_lease`); null without a hand.

A request that fails answers ``{"ok": false, "error": "..."}`` (an unknown fault or
parameter names the key).  Requests act at the simulation time of the moment they are read,
as host input does.  The socket lives only on this machine (a path, not a network port).
"""

from __future__ import annotations

import json
import os
import socket
import stat
from typing import TYPE_CHECKING, Any

from firmware_py.fmcb import FmcbApp
from hil_emulator.errors import EmulatorError, PortError
from hil_emulator.faults.base import FAULTS
from hil_emulator.faults.injector import FaultInjector

if TYPE_CHECKING:
    from hil_emulator.emulator import Emulator


def _clear_stale(path: str) -> None:
    """Remove a control socket left by an emulator that has gone; refuse one an emulator
    still listens on, and anything that is not a socket."""
    if not os.path.lexists(path):
        return
    if not stat.S_ISSOCK(os.lstat(path).st_mode):
        raise PortError(f"cannot listen on the control socket {path}: it exists and is not "
                        "a socket (remove it, or give another path)")
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as probe:
        try:
            probe.connect(path)
        except OSError:
            os.unlink(path)  # nobody listens: a stale socket
            return
    raise PortError(f"cannot listen on the control socket {path}: a running emulator "
                    "listens there (stop it first, or give another path)")


class ControlChannel:
    """A listening unix socket at ``path``, injecting through ``faults`` (a new
    :class:`FaultInjector` of ``emulator`` if not given).  Give it to the emulator to serve
    (:meth:`Emulator.add_port <hil_emulator.emulator.Emulator.add_port>`: its loop calls
    :meth:`poll`)."""

    name = "control"

    def __init__(self, emulator: Emulator, path: str,
                 faults: FaultInjector | None = None) -> None:
        self.emulator = emulator
        self.path = path
        #: The injector requests act through (its timeline is the ``timeline`` answer).
        self.faults = faults if faults is not None else FaultInjector(emulator)
        _clear_stale(path)
        self._server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            self._server.bind(path)
            self._inode: int | None = os.stat(path).st_ino  # removed on close only if ours
        except OSError as exc:
            self._server.close()
            raise PortError(f"cannot listen on the control socket {path}: {exc}") from exc
        self._server.listen(4)
        self._server.setblocking(False)
        self._clients: dict[socket.socket, bytearray] = {}
        self.requests = 0

    def fileno(self) -> int:
        """The listening socket (clients are polled every loop)."""
        return self._server.fileno()

    def poll(self) -> int:
        """Accept clients, answer every complete line; returns the requests handled."""
        handled = 0
        while True:
            try:
                client, _ = self._server.accept()
            except (BlockingIOError, OSError):
                break
            client.setblocking(False)
            self._clients[client] = bytearray()
        for client, buffer in list(self._clients.items()):
            try:
                chunk = client.recv(65536)
            except BlockingIOError:
                continue
            except OSError:
                chunk = b""
            if not chunk:
                self._drop(client)
                continue
            buffer += chunk
            while b"\n" in buffer:
                line, _, rest = bytes(buffer).partition(b"\n")
                buffer[:] = rest
                if line.strip():
                    self._answer(client, self.handle_line(line))
                    handled += 1
        self.requests += handled
        return handled

    def handle_line(self, line: bytes) -> dict[str, Any]:
        """The answer to one request line."""
        try:
            request = json.loads(line)
        except ValueError as exc:  # JSONDecodeError and undecodable UTF-8
            return {"ok": False, "error": f"not a JSON line ({exc}): each request is one "
                    'JSON object on a line, e.g. {"op": "status"}'}
        try:
            if not isinstance(request, dict):
                raise ValueError('a request is a JSON object, e.g. {"op": "status"}')
            return {"ok": True, **self.handle(request)}
        except (ValueError, KeyError, TypeError, EmulatorError) as exc:
            return {"ok": False, "error": str(exc)}

    def handle(self, request: dict[str, Any]) -> dict[str, Any]:
        """Carry out one request (see the module's table)."""
        faults = self.faults
        op = request.get("op")
        if op == "inject":
            entry = faults.inject(str(request["fault"]), request.get("params") or {},
                                  at_s=float(request.get("at_s") or 0.0),
                                  duration_s=request.get("duration_s"),
                                  label=request.get("label"))
            return {"id": entry, "t_us": self.emulator.scheduler.now_us()}
        if op == "clear":
            faults.clear(int(request["id"]))
            return {}
        if op == "clear_all":
            faults.clear_all()
            return {}
        if op == "active":
            return {"ids": faults.active}
        if op == "timeline":
            return {"events": faults.timeline_dicts()}
        if op == "list":
            return {"faults": sorted(FAULTS)}
        if op == "status":
            return {"t_us": self.emulator.scheduler.now_us(), **self.emulator.lateness_stats()}
        if op == "truth":
            return {"t_us": self.emulator.scheduler.now_us(), "arm": self._arm_truth(),
                    "hand": self._hand_truth()}
        raise ValueError(f"unknown op {op!r}: inject, clear, clear_all, active, timeline, list, "
                         "status, truth")

    def _arm_truth(self) -> dict[str, Any] | None:
        """The arm plant's joints and its nodes' torque and alarm state (see the module)."""
        rig, plant = self.emulator.arm, self.emulator.arm_plant
        if rig is None or plant is None:
            return None
        nodes: dict[str, dict[str, int]] = {}
        for dxl_id in sorted(rig.nodes):
            app = rig.app(dxl_id)
            flags = app.get("status_flags") if "status_flags" in app.table else 0
            nodes[str(dxl_id)] = {"torque_enable": app.get("torque_enable"),
                                  "status_flags": flags, "alarms": app.alarm_bits()}
        return {"joints": [float(v) for v in plant.joint_angles()],
                "velocities": [float(v) for v in plant.joint_velocities()],
                "deflections": [float(v) for v in plant.deflections()],
                "nodes": nodes}

    def _hand_truth(self) -> dict[str, Any] | None:
        """Each finger's fmcb joint limits and lease (see the module)."""
        rig = self.emulator.hand
        if rig is None:
            return None
        fingers: list[dict[str, Any] | None] = []
        for finger in rig.fingers:
            app = finger.fmcb.program
            if not isinstance(app, FmcbApp):
                fingers.append(None)
                continue
            p = app.params
            fingers.append({"joint_limits": [[float(p[f"joint_lower_{j}"]),
                                              float(p[f"joint_upper_{j}"])] for j in range(3)],
                            "limit_lease": app.limit_lease.active})
        return {"fingers": fingers}

    def _answer(self, client: socket.socket, answer: dict[str, Any]) -> None:
        try:
            client.sendall(json.dumps(answer).encode() + b"\n")
        except OSError:
            self._drop(client)

    def _drop(self, client: socket.socket) -> None:
        self._clients.pop(client, None)
        client.close()

    def stats(self) -> dict[str, int]:
        """Requests answered, for ``--stats``."""
        return {"requests": self.requests}

    def close(self) -> None:
        """Close every connection and remove the socket (idempotent)."""
        for client in list(self._clients):
            self._drop(client)
        if self._server.fileno() >= 0:
            self._server.close()
            try:
                if os.stat(self.path).st_ino == self._inode:
                    os.unlink(self.path)
            except FileNotFoundError:
                pass
