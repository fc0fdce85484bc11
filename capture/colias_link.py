"""The serial link to a Colias-IV: the host side (pyserial, reconnecting) and a robot emulator.

``RobotEmulator`` opens a pseudo-terminal, keeps a stable symlink to it, and speaks the protocol
of ``capture.serial_protocol`` with frames and on-board AVDM outputs from the simulator; it can
corrupt bytes, drop packets and disconnect (closing its pty; after a pause it opens a new one
behind the same symlink, as a robot that is power-cycled or a cable that is re-plugged).

``SerialLink`` is the host side: it opens the port (through the symlink), sends START, turns the
byte stream into packets, and reopens the port after it disappears.
"""

from __future__ import annotations

import dataclasses
import fcntl
import json
import os
import pty
import struct
import termios
import time
import tty
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import serial

from avdm.registry import make_model
from capture.config import SimConfig
from capture.serial_protocol import (
    TYPE_END,
    TYPE_FRAME,
    TYPE_PARAMS,
    TYPE_START,
    TYPE_STOP,
    PacketParser,
    decode_frame,
    encode,
    encode_frame,
)
from capture.sim_robot import SimulatedRobot
from vdc.cli_support import non_negative_float, non_negative_int, option, positive_float


@dataclasses.dataclass(frozen=True)
class EmulatorConfig:
    corrupt_rate: float = 0.0  # share of packets corrupted (1–3 bits flipped past the sync word)
    drop_rate: float = 0.0  # probability of not sending a packet
    disconnect_after_s: float = float("nan")  # close the port once, this long after START
    reconnect_after_s: float = 1.0  # the port reappears this long after a disconnect
    decimation: int = 1  # send the image with every Nth frame
    realtime: bool = True  # pace frames at the camera rate
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("corrupt_rate", "drop_rate"):
            v = getattr(self, name)
            if not 0.0 <= v < 1.0:
                raise ValueError(f"{name}={v!r} must be in [0, 1)")
        if not (isinstance(self.decimation, int) and 1 <= self.decimation <= 1000):
            raise ValueError(f"decimation={self.decimation!r} must be an integer 1-1000")


class RobotEmulator:
    """A simulated Colias-IV behind a pseudo-terminal, with fault injection.

    ``report`` (written to ``report_path`` at the end) counts what was injected: frames sent
    intact, corrupted, dropped and lost in the disconnect."""

    def __init__(
        self, sim: SimConfig, emu: EmulatorConfig, link: Path, report_path: Path | None = None
    ) -> None:
        self.sim = sim
        self.emu = emu
        self.link = link
        self.report_path = report_path
        self.rng = np.random.default_rng(emu.seed)
        self.report = {
            "frames": 0,
            "intact": [],
            "corrupted": [],
            "dropped": [],
            "lost_in_disconnect": [],
            "disconnects": 0,
        }
        self._master: int | None = None
        self._slave: int | None = None
        self._lost: set[int] = set()

    # -- the port ---------------------------------------------------------------------------
    def _check_link(self) -> None:
        """The link may replace only a link to a pseudo-terminal (an earlier emulator's):
        never a file or a link the user made."""
        link = self.link
        if link.is_symlink():
            if not os.readlink(link).startswith("/dev/pts/"):
                raise ValueError(
                    f"--link {str(link)!r} is a link to {os.readlink(link)!r}, not to an "
                    "emulator's terminal; choose another path"
                )
        elif link.exists():
            raise ValueError(f"--link {str(link)!r} exists and is not a link; choose another path")

    def open_port(self) -> str:
        self._check_link()
        master, slave = pty.openpty()
        tty.setraw(slave)  # bytes pass untouched: no echo, no newline translation
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        name = os.ttyname(slave)
        tmp = self.link.with_name(f".{self.link.name}.{os.getpid()}.tmp")  # ours alone
        tmp.unlink(missing_ok=True)
        tmp.symlink_to(name)
        tmp.replace(self.link)  # atomic: the host never sees a half-made link
        return name

    def close_port(self) -> None:
        if self.link.is_symlink():  # first, so the host cannot reopen a dying port
            self.link.unlink()
        for fd in (self._master, self._slave):
            if fd is not None:
                os.close(fd)
        self._master = self._slave = None

    def _write(self, data: bytes) -> bool:
        """Write all of ``data`` (waits while the pty buffer is full); False if the port closed."""
        view = memoryview(data)
        while view:
            try:
                n = os.write(self._master, view)  # type: ignore[arg-type]
            except BlockingIOError:
                time.sleep(0.001)
                continue
            except OSError:
                return False
            view = view[n:]
        return True

    def _drain(self, timeout_s: float = 2.0) -> None:
        """Wait until the host has read everything written so far (or ``timeout_s``)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                pending = struct.unpack(
                    "i", fcntl.ioctl(self._slave, termios.FIONREAD, b"\0\0\0\0")
                )[0]
            except OSError:
                return
            if pending == 0:
                return
            time.sleep(0.005)

    def _read_host(self) -> list[int]:
        """Packet types the host sent since the last call."""
        try:
            data = os.read(self._master, 4096)  # type: ignore[arg-type]
        except (BlockingIOError, OSError):
            return []
        return [t for t, _ in self._parser.feed(data)]

    def _wait_for_start(self, deadline: float) -> bool:
        while time.monotonic() < deadline:
            if TYPE_START in self._read_host():
                return True
            time.sleep(0.01)
        return False

    # -- the run ----------------------------------------------------------------------------
    def run(self, wait_for_host_s: float = 60.0, announce=None) -> dict:
        sim = self.sim
        model = make_model(sim.model, **sim.camera.model_context())
        shape = (sim.camera.height_px, sim.camera.width_px)
        self._parser = PacketParser()
        name = self.open_port()
        if announce is not None:
            announce(name)
        if not self._wait_for_start(time.monotonic() + wait_for_host_s):
            self.close_port()
            raise TimeoutError("no host sent START")
        started = time.monotonic()
        disconnect_at = self.emu.disconnect_after_s
        period = 1.0 / sim.camera.fps
        with SimulatedRobot(sim) as robot:
            while (batch := robot.read()) is not None:
                outputs = model.run(batch.images)
                for i, f in enumerate(batch.frame):
                    f = int(f)
                    if self.emu.realtime:
                        delay = started + f * period - time.monotonic()
                        if delay > 0:
                            time.sleep(delay)
                    if not np.isnan(disconnect_at) and time.monotonic() - started >= disconnect_at:
                        disconnect_at = float("nan")
                        self._disconnect(batch, outputs, i)
                    if TYPE_STOP in self._read_host():
                        self._finish()
                        return self.report
                    self.report["frames"] += 1
                    if f in self._lost:
                        continue
                    if self.rng.random() < self.emu.drop_rate:
                        self.report["dropped"].append(f)
                        continue
                    image = batch.images[i] if f % self.emu.decimation == 0 else None
                    values = [float(outputs[o.name][i]) for o in model.outputs]
                    packet = bytearray(
                        encode_frame(f, round(batch.t_s[i] * 1e6), values, image, shape)
                    )
                    corrupt = self.rng.random() < self.emu.corrupt_rate
                    if corrupt:
                        for k in self.rng.integers(
                            2, len(packet), size=int(self.rng.integers(1, 4))
                        ):
                            packet[k] ^= 1 << int(self.rng.integers(8))
                    (self.report["corrupted"] if corrupt else self.report["intact"]).append(f)
                    if not self._write(bytes(packet)):
                        break
        self._finish()
        return self.report

    def _disconnect(self, batch, outputs, i: int) -> None:
        """Close the port, stay away for reconnect_after_s, reopen behind the same link."""
        self.report["disconnects"] += 1
        self._drain()  # what was sent before the cable "comes out" reaches the host
        self.close_port()
        gone = time.monotonic()
        frames_away = round(self.emu.reconnect_after_s * self.sim.camera.fps)
        first = int(batch.frame[i])
        self._lost = set(range(first, first + frames_away))
        self.report["lost_in_disconnect"] = sorted(self._lost)
        time.sleep(max(0.0, self.emu.reconnect_after_s - (time.monotonic() - gone)))
        self._parser = PacketParser()
        self.open_port()
        self._wait_for_start(time.monotonic() + 30.0)

    def _finish(self) -> None:
        self._write(encode(TYPE_END))
        time.sleep(0.2)
        self.close_port()
        if self.report_path is not None:
            self.report_path.write_text(json.dumps(self.report), encoding="utf-8")


class LinkLost(Exception):
    """The port did not come back within the reconnect timeout."""


class SerialLink:
    """Host side of the link: packets in, START/STOP/PARAMS out, reconnecting on loss."""

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

    def open(self) -> None:
        """Open the port and ask the robot to start; raises serial.SerialException."""
        self._ser = serial.Serial(self.port, self.baud, timeout=0.05)
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
            except (serial.SerialException, OSError):
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
            except (serial.SerialException, OSError) as exc:
                last = str(exc)
        raise LinkLost(
            f"the port {self.port} did not come back within {self.reconnect_timeout_s:g} s "
            f"(last error: {last})"
        )

    def packets(self) -> Iterator[tuple[int, object]]:
        """(type, FramePacket or payload) as they arrive; ends when the robot sends END.
        Yields (0, None) about every 50 ms while the line is quiet, so callers can stop."""
        while not self.ended:
            try:
                # read only what is waiting: a read that spans the moment the port vanishes
                # would otherwise lose the bytes it had already gathered
                waiting = self._ser.in_waiting if self._ser is not None else 0
                data = self._ser.read(waiting or 1) if self._ser is not None else b""
            except (serial.SerialException, OSError, TypeError):
                yield (0, "disconnect")
                self._reconnect()
                continue
            if not data:
                if time.monotonic() - self._last_data > 2.0 and self._ser is not None:
                    # silent for 2 s: a START may have been lost; asking again is harmless
                    self._ser.write(encode(TYPE_START))
                    self._last_data = time.monotonic()
                yield (0, None)
                continue
            self._last_data = time.monotonic()
            for ptype, payload in self.parser.feed(data):
                if ptype == TYPE_FRAME:
                    try:
                        yield (ptype, decode_frame(payload))
                    except ValueError:
                        self.parser.stats.bad_length += 1
                elif ptype == TYPE_END:
                    self.ended = True
                    return


@dataclasses.dataclass(frozen=True)
class EmulateSettings:
    """``vdc-capture emulate-robot`` as a settings object (one field per flag, same names)."""

    link: str = option("/tmp/vdc-robot", "stable path (symlink) to the emulated port")
    tf_hz: float = option(0.0, "wall TF, Hz", type=non_negative_float)
    minutes: float = option(1.0, "run length", type=positive_float)
    seed: int = option(0, "random seed", type=non_negative_int)
    model: str = option(
        "avdm",
        "the model the emulated robot runs on board (any model, a plug-in too); give "
        "vdc-capture robot the same --model",
    )
    corrupt_rate: float = option(
        0.0,
        "share of packets corrupted, e.g. 0.01 (1-3 bits flipped in each)",
        type=non_negative_float,
    )
    drop_rate: float = option(0.0, "probability of dropping each packet", type=non_negative_float)
    disconnect_after: float | None = option(
        None, "close the port once, this many seconds after START", type=positive_float
    )
    reconnect_after: float = option(1.0, "seconds until the port reappears", type=positive_float)
    decimation: int = option(1, "send the image with every Nth frame (slow links)")
    fast: bool = option(False, "do not pace frames at 33 Hz")
    wait: float = option(60.0, "seconds to wait for the host", type=positive_float)
    report: str | None = option(None, "write what was injected to this JSON file")


def emulate_robot(settings: EmulateSettings, announce: Callable[[str], None] | None = None) -> dict:
    """Run a simulated Colias-IV on a pseudo-terminal behind ``settings.link`` until its run
    ends; ``announce`` gets the pty's name once it exists. Returns what was injected (frames
    intact, corrupted, dropped, lost in disconnects). ValueError if no host sends START."""
    from capture.config import CameraConfig, WallConfig

    emu = EmulatorConfig(
        corrupt_rate=settings.corrupt_rate,
        drop_rate=settings.drop_rate,
        disconnect_after_s=settings.disconnect_after or float("nan"),
        reconnect_after_s=settings.reconnect_after,
        decimation=settings.decimation,
        realtime=not settings.fast,
        seed=settings.seed,
    )
    sim = SimConfig(
        wall=WallConfig(tf_schedule=((settings.tf_hz, settings.minutes * 60),)),
        camera=CameraConfig(),
        duration_s=settings.minutes * 60,
        seed=settings.seed,
        model=settings.model,
    )
    robot = RobotEmulator(
        sim, emu, Path(settings.link), Path(settings.report) if settings.report else None
    )
    try:
        return robot.run(wait_for_host_s=settings.wait, announce=announce)
    except TimeoutError as exc:
        raise ValueError(str(exc)) from None
