"""The loopback controller's client sessions: RTDE (30004), the dashboard (29999) and the script port
(30003), each a non-blocking socket the controller's selector loop feeds."""

from __future__ import annotations

import re
import socket
import struct
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from hec.rehearsal.rtde_protocol import (
    RTDE_CONTROLLER_VERSION,
    RTDE_DATA,
    RTDE_HEADER,
    RTDE_PAUSE,
    RTDE_PROTOCOL_VERSION,
    RTDE_SETUP_INPUTS,
    RTDE_SETUP_OUTPUTS,
    RTDE_START,
    TYPE_CODES,
    VECTOR_SIZES,
    input_type,
    output_type,
)


class SessionHost(Protocol):
    """What a session needs of the controller that accepted it."""

    config: Any
    inputs: dict[str, Any]
    input_owners: dict[str, Any]
    max_frequency_hz: float

    def close_session(self, session: Session) -> None: ...
    def watch_writes(self, session: Session, pending: bool) -> None: ...
    def event(self, text: str) -> None: ...
    def dashboard(self, request: str) -> str: ...
    def program_received(self, text: str) -> None: ...


class Session:
    """A client connection with non-blocking buffered output."""

    # A client that lets this much output pile up is dropped, as the real controller does.
    MAX_PENDING_BYTES = 1 << 20

    def __init__(self, controller: SessionHost, sock: socket.socket, port: int) -> None:
        self.controller = controller
        self.sock = sock
        self.port = port
        self.inbox = bytearray()
        self.outbox = bytearray()
        self.closed = False

    def on_open(self) -> None:
        """Called once the session is registered with the selector."""

    def send(self, data: bytes) -> None:
        if self.closed:
            return
        self.outbox += data
        self.flush()

    def flush(self) -> None:
        try:
            while self.outbox:
                sent = self.sock.send(self.outbox)
                del self.outbox[:sent]
        except BlockingIOError:
            if len(self.outbox) > self.MAX_PENDING_BYTES:
                self.controller.event(f"port {self.port}: client does not read, dropping it")
                self.controller.close_session(self)
                return
        except OSError:
            self.controller.close_session(self)
            return
        self.controller.watch_writes(self, bool(self.outbox))

    def on_readable(self) -> None:
        try:
            data = self.sock.recv(65536)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            self.controller.close_session(self)
            return
        self.inbox += data
        self.on_data()

    def on_data(self) -> None:
        raise NotImplementedError


class RtdeSession(Session):
    """One RTDE client (protocol version 2)."""

    def __init__(self, controller: SessionHost, sock: socket.socket, port: int) -> None:
        super().__init__(controller, sock, port)
        self.output_names: list[str] = []
        self.output_struct: struct.Struct | None = None
        self.period_s = 1.0
        self.credit_s = 0.0
        self.started = False
        self.input_recipes: dict[int, tuple[list[str], list[str], struct.Struct]] = {}

    def reply(self, message_type: int, payload: bytes) -> None:
        self.send(RTDE_HEADER.pack(RTDE_HEADER.size + len(payload), message_type) + payload)

    def on_data(self) -> None:
        while len(self.inbox) >= RTDE_HEADER.size and not self.closed:
            size, message_type = RTDE_HEADER.unpack_from(self.inbox)
            if size < RTDE_HEADER.size:
                self.controller.event("RTDE: malformed header, dropping the client")
                self.controller.close_session(self)
                return
            if len(self.inbox) < size:
                return
            payload = bytes(self.inbox[RTDE_HEADER.size : size])
            del self.inbox[:size]
            self.handle(message_type, payload)

    def handle(self, message_type: int, payload: bytes) -> None:
        if message_type == RTDE_DATA:
            self.receive_inputs(payload)
        elif message_type == RTDE_PROTOCOL_VERSION:
            (version,) = struct.unpack(">H", payload[:2])
            self.reply(message_type, bytes([version == 2]))
        elif message_type == RTDE_CONTROLLER_VERSION:
            self.reply(message_type, struct.pack(">4I", *self.controller.config.controller_version))
        elif message_type == RTDE_SETUP_OUTPUTS:
            self.setup_outputs(payload)
        elif message_type == RTDE_SETUP_INPUTS:
            self.setup_inputs(payload)
        elif message_type == RTDE_START:
            self.started = self.output_struct is not None
            self.credit_s = self.period_s
            self.reply(message_type, bytes([self.started]))
        elif message_type == RTDE_PAUSE:
            self.started = False
            self.reply(message_type, b"\x01")
        else:
            self.controller.event(f"RTDE: ignored message type {message_type}")

    def setup_outputs(self, payload: bytes) -> None:
        (frequency,) = struct.unpack(">d", payload[:8])
        names = [name for name in payload[8:].decode("ascii").split(",") if name]
        types = [output_type(name) or "NOT_FOUND" for name in names]
        valid = bool(names) and "NOT_FOUND" not in types and frequency > 0
        if valid:
            self.output_names = names
            self.output_struct = struct.Struct(">B" + "".join(TYPE_CODES[t] for t in types))
            # The controller cannot stream faster than its control loop.
            self.period_s = 1.0 / min(frequency, self.controller.max_frequency_hz)
        self.reply(RTDE_SETUP_OUTPUTS, bytes([1 if valid else 0]) + ",".join(types).encode("ascii"))

    def setup_inputs(self, payload: bytes) -> None:
        names = [name for name in payload.decode("ascii").split(",") if name]
        types = [input_type(name) or "NOT_FOUND" for name in names]
        owners = self.controller.input_owners
        types = [
            "IN_USE" if owners.get(name, self) is not self else t
            for name, t in zip(names, types, strict=True)
        ]
        if names and all(t in TYPE_CODES for t in types):
            recipe_id = len(self.input_recipes) + 1
            self.input_recipes[recipe_id] = (
                names,
                types,
                struct.Struct(">B" + "".join(TYPE_CODES[t] for t in types)),
            )
            for name in names:
                owners[name] = self
        else:
            recipe_id = 0
        self.reply(RTDE_SETUP_INPUTS, bytes([recipe_id]) + ",".join(types).encode("ascii"))

    def receive_inputs(self, payload: bytes) -> None:
        recipe = self.input_recipes.get(payload[0]) if payload else None
        if recipe is None or recipe[2].size != len(payload):
            self.controller.event(f"RTDE: ignored input package of {len(payload)} bytes")
            return
        names, types, layout = recipe
        values = layout.unpack(payload)[1:]
        position = 0
        for name, rtde_type in zip(names, types, strict=True):
            count = VECTOR_SIZES.get(rtde_type, 1)
            value = values[position : position + count]
            self.controller.inputs[name] = list(value) if count > 1 else value[0]
            position += count

    def stream(self, tick_s: float, values: Callable[[str], Any]) -> None:
        """Called every control tick of tick_s seconds: send a data package if one is due."""
        if not self.started or self.output_struct is None:
            return
        self.credit_s += tick_s
        if self.credit_s < self.period_s - 1e-9:
            return
        self.credit_s = min(self.credit_s - self.period_s, self.period_s)
        fields: list[Any] = [1]
        for name in self.output_names:
            value = values(name)
            if isinstance(value, list | tuple | np.ndarray):
                fields.extend(value)
            else:
                fields.append(value)
        self.reply(RTDE_DATA, self.output_struct.pack(*fields))


class DashboardSession(Session):
    """One dashboard client: a line in, a line out."""

    def on_open(self) -> None:
        self.send(b"Connected: Universal Robots Dashboard Server\n")

    def on_data(self) -> None:
        while b"\n" in self.inbox and not self.closed:
            line, _, rest = bytes(self.inbox).partition(b"\n")
            self.inbox[:] = rest
            request = line.decode("utf-8", "replace").strip()
            self.send((self.controller.dashboard(request) + "\n").encode("utf-8"))
            if request == "quit":
                self.controller.close_session(self)


class ScriptSession(Session):
    """One script client: programs (``def name():`` .. ``end``) or single lines of URScript."""

    def on_data(self) -> None:
        while True:
            text = self.inbox.decode("utf-8", "replace")
            stripped = text.lstrip()
            if not stripped:
                self.inbox.clear()
                return
            if re.match(r"(def|sec)\s", stripped):
                end = re.search(r"^end[ \t]*\r?$\n?", stripped, re.MULTILINE)
                if end is None:
                    return
                program = stripped[: end.end()]
            elif "\n" in stripped:
                program = stripped[: stripped.index("\n") + 1]
            else:
                return
            self.inbox[:] = stripped[len(program) :].encode("utf-8")
            self.controller.program_received(program)
