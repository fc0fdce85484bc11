"""The host's end of the serial link to a Colias-IV (pyserial, reconnecting).

``SerialLink`` opens the port (through the emulator's or udev's symlink), sends PARAMS and START,
waits for the robot's ANNOUNCE (:meth:`SerialLink.handshake`), turns the byte stream into
packets, and reopens the port after it disappears. The robot's end, emulated, is
``capture.robot_emulator``.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Iterable, Iterator

import serial

from capture.serial_protocol import (
    TYPE_ANNOUNCE,
    TYPE_END,
    TYPE_FRAME,
    TYPE_PARAMS,
    TYPE_START,
    TYPE_STOP,
    Announcement,
    FramePacket,
    PacketParser,
    decode_announce,
    decode_frame,
    encode,
)

try:  # pyserial's POSIX flush() raises termios.error (not an OSError) once the far end is gone
    from termios import error as _TermiosError
except ImportError:  # Windows
    _TermiosError = OSError

# what a vanished port raises, from any of pyserial's calls
PORT_ERRORS: tuple[type[BaseException], ...] = (serial.SerialException, OSError, _TermiosError)


class LinkLost(Exception):
    """The port did not come back within the reconnect timeout."""


class SerialLink:
    """Host side of the link: packets in, PARAMS/START/STOP out, reconnecting on loss.

    ``params`` (a model spec) goes to the robot before every START; :meth:`handshake` waits for
    the robot's ANNOUNCE. Packets read meanwhile are kept for :meth:`packets`."""

    def __init__(
        self, port: str, baud: int = 3_000_000, reconnect_timeout_s: float = 30.0, params: str = ""
    ) -> None:
        self.port = port
        self.baud = baud
        self.reconnect_timeout_s = reconnect_timeout_s
        self.params = params
        self.parser = PacketParser()
        self.disconnects = 0
        self.ended = False
        self._ser: serial.Serial | None = None
        self._last_data = time.monotonic()
        # read but not yet yielded (during the handshake, or behind a packet a caller took)
        self._pending: deque[tuple[int, object]] = deque()
        self._lost = False  # the port vanished; reopen it before reading on
        self.announcements: list[Announcement] = []  # every ANNOUNCE, in order
        self.no_announce = ""  # why the handshake got no ANNOUNCE

    def _decoded(self, data: bytes) -> list[tuple[int, object]]:
        """(type, FramePacket | Announcement | None) of the whole packets in ``data``; a FRAME
        or ANNOUNCE whose payload does not match its header is counted as bad_length."""
        return self._decoded_packets(self.parser.feed(data))

    def _decoded_packets(self, packets: Iterable[tuple[int, bytes]]) -> list[tuple[int, object]]:
        out: list[tuple[int, object]] = []
        for ptype, payload in packets:
            try:
                if ptype == TYPE_FRAME:
                    out.append((ptype, decode_frame(payload)))
                elif ptype == TYPE_ANNOUNCE:
                    a = decode_announce(payload)
                    self.announcements.append(a)
                    out.append((ptype, a))
                elif ptype == TYPE_END:
                    out.append((ptype, None))
            except ValueError:
                self.parser.stats.bad_length += 1
        return out

    def handshake(self, timeout_s: float) -> Announcement | None:
        """The robot's ANNOUNCE after the START that :meth:`open` sent, or None when it does
        not come within ``timeout_s`` or a FRAME or END comes first (firmware that never
        announces); ``no_announce`` then says which."""
        deadline = time.monotonic() + timeout_s
        self.no_announce = f"no answer within {timeout_s:g} s of START"
        while time.monotonic() < deadline and self._ser is not None:
            waiting = self._ser.in_waiting
            got = self._decoded(self._ser.read(waiting or 1))
            for k, (ptype, obj) in enumerate(got):
                if ptype == TYPE_ANNOUNCE:
                    self._pending += got[k + 1 :]
                    return obj  # type: ignore[return-value]
                if ptype in (TYPE_FRAME, TYPE_END):
                    self._pending += got[k:]
                    self.no_announce = "it sent frames without announcing"
                    return None
        return None

    def first_frame(self, timeout_s: float) -> FramePacket | None:
        """The run's first FRAME, waiting up to ``timeout_s`` for it (None if none comes, or
        END or another ANNOUNCE comes first); what is read is kept for :meth:`packets`."""
        for ptype, obj in self._pending:
            if ptype != TYPE_FRAME:
                return None
            return obj  # type: ignore[return-value]
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and self._ser is not None:
            got = self._decoded(self._ser.read(self._ser.in_waiting or 1))
            self._pending += got
            if got:
                return got[0][1] if got[0][0] == TYPE_FRAME else None  # type: ignore[return-value]
        return None

    def open(self) -> None:
        """Open the port and ask the robot to start; raises serial.SerialException."""
        self._ser = serial.Serial(self.port, self.baud, timeout=0.05)
        self._send_start()

    def _send_start(self) -> None:
        """PARAMS (the model the host asks for), then START."""
        if self._ser is None:
            return
        if self.params:
            self._ser.write(encode(TYPE_PARAMS, self.params.encode()))
        self._ser.write(encode(TYPE_START))
        self._ser.flush()

    def close(self, stop: bool = True) -> None:
        if self._ser is not None:
            try:
                if stop:
                    self._ser.write(encode(TYPE_STOP))
                    self._ser.flush()
            except PORT_ERRORS:
                pass
            self._ser.close()
            self._ser = None

    def _reconnect(self) -> None:
        self.close(stop=False)
        self.disconnects += 1
        self.parser.buf.clear()  # a half packet from before the loss is gone for good
        deadline = time.monotonic() + self.reconnect_timeout_s
        last = "no attempt"
        while time.monotonic() < deadline:
            time.sleep(0.1)
            try:
                self.open()
                return
            except PORT_ERRORS as exc:
                last = str(exc)
        raise LinkLost(
            f"the port {self.port} did not come back within {self.reconnect_timeout_s:g} s "
            f"(last error: {last})"
        )

    def packets(self) -> Iterator[tuple[int, object]]:
        """(type, FramePacket or Announcement) as they arrive; ends when the robot sends END.
        Yields (0, None) about every 50 ms while the line is quiet, so callers can stop, and
        (0, "disconnect") when the port is lost (it is reopened before the next packet).

        A caller may stop iterating at any packet and call again: whatever was read but not
        yet yielded waits in the link, not in the generator. (It once lived in the generator,
        and a capture that ended its batch on the first of several packets read together
        dropped the rest, the robot's END among them: the host then waited for a robot that
        had finished.)"""
        while not self.ended:
            if self._lost:
                self._reconnect()  # LinkLost leaves it lost: a later call tries again
                self._lost = False
            if self._pending:
                ptype, obj = self._pending.popleft()
                if ptype == TYPE_END:
                    self.ended = True
                    return
                yield (ptype, obj)
                continue
            try:
                # read only what is waiting: a read that spans the moment the port vanishes
                # would otherwise lose the bytes it had already gathered
                waiting = self._ser.in_waiting if self._ser is not None else 0
                data = self._ser.read(waiting or 1) if self._ser is not None else b""
            except (*PORT_ERRORS, TypeError):
                self._lost = True
                yield (0, "disconnect")
                continue
            if not data:
                quiet_s = time.monotonic() - self._last_data
                if quiet_s > 0.3 and self.parser.buf:
                    # nothing more is coming for now: free any packet a damaged length holds
                    self._pending += self._decoded_packets(self.parser.salvage())
                    if self._pending:
                        continue
                if quiet_s > 2.0 and self._ser is not None:
                    # silent for 2 s: a START may have been lost; asking again is harmless
                    try:
                        self._send_start()
                    except PORT_ERRORS:
                        self._lost = True
                        yield (0, "disconnect")
                        continue
                    self._last_data = time.monotonic()
                yield (0, None)
                continue
            self._last_data = time.monotonic()
            self._pending += self._decoded(data)
