"""A Colias-IV robot emulator: the robot's end of the serial link, on a pseudo-terminal.

``RobotEmulator`` opens a pseudo-terminal, keeps a stable symlink to it, and speaks the protocol
of ``capture.serial_protocol`` with frames and on-board model outputs from the simulator: it runs
the model the host's PARAMS asks for (or a model of its own, fixed, so tests can make the two
ends disagree), announces it with its camera after each START (unless it plays older firmware
that never does), and can corrupt bytes, drop packets and disconnect (closing its pty; after a
pause it opens a new one behind the same symlink, as a robot that is power-cycled or a cable
that is re-plugged). The host's end is ``capture.serial_link``.
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
from collections import deque
from collections.abc import Callable
from pathlib import Path

import numpy as np

from avdm.registry import canonical_name, make_model
from capture.config import CameraConfig, SimConfig, WallConfig
from capture.serial_protocol import (
    TYPE_END,
    TYPE_PARAMS,
    TYPE_START,
    TYPE_STOP,
    Announcement,
    PacketParser,
    encode,
    encode_announce,
    encode_frame,
)
from capture.sim_robot import SimulatedRobot
from vdc.cli_support import option
from vdc.errors import UserError
from vdc.settings import AT_LEAST_0, AT_LEAST_1, FRACTION, POSITIVE, Settings, between


@dataclasses.dataclass(frozen=True)
class EmulatorConfig:
    corrupt_rate: float = 0.0  # share of packets corrupted (1–3 bits flipped past the sync word)
    drop_rate: float = 0.0  # probability of not sending a packet
    # close the port once, at this robot time after START (the frame at disconnect_after_s x
    # fps): at the same frame whatever the load, though a host that reads late sees it sooner
    disconnect_after_s: float = float("nan")
    reconnect_after_s: float = 1.0  # the port reappears this long after a disconnect
    decimation: int = 1  # send the image with every Nth frame
    realtime: bool = True  # pace frames at the camera rate
    seed: int = 0
    # the model it runs: "" = the one the host's PARAMS asks for (avdm if it sends none);
    # a spec = that model whatever the host asks (so tests can make the two ends disagree)
    fixed_model: str = ""
    silent: bool = False  # older firmware: ignores PARAMS and never sends ANNOUNCE

    def __post_init__(self) -> None:
        for name in ("corrupt_rate", "drop_rate"):
            v = getattr(self, name)
            if not 0.0 <= v < 1.0:
                raise UserError(f"{name}={v!r} must be in [0, 1).")
        if not (isinstance(self.decimation, int) and 1 <= self.decimation <= 1000):
            raise UserError(f"decimation={self.decimation!r} must be an integer 1-1000.")


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
        # the last packets written: (frame, bytes, report list), to tell which a disconnect
        # cut off before the host read them
        self._sent: deque[tuple[int, int, str]] = deque(maxlen=256)

    # -- the port ---------------------------------------------------------------------------
    def _check_link(self) -> None:
        """The link may replace only a link to a pseudo-terminal (an earlier emulator's):
        never a file or a link the user made."""
        link = self.link
        if link.is_symlink():
            if not os.readlink(link).startswith("/dev/pts/"):
                raise UserError(
                    f"--link {str(link)!r} is a link to {os.readlink(link)!r}, not to an "
                    "emulator's terminal; choose another path."
                )
        elif link.exists():
            raise UserError(f"--link {str(link)!r} exists and is not a link; choose another path.")

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
        """Write all of ``data`` (waits while the pty buffer is full, reading the host's packets
        meanwhile); False if the port closed or the host sent STOP."""
        view = memoryview(data)
        while view:
            try:
                n = os.write(self._master, view)  # type: ignore[arg-type]
            except BlockingIOError:
                # a host that stopped reading may be waiting for us to read its STOP
                if TYPE_STOP in self._read_host():
                    self.stopped = True
                if self.stopped:
                    return False
                time.sleep(0.001)
                continue
            except OSError:
                return False
            view = view[n:]
        return True

    def _pending_bytes(self) -> int:
        """Bytes written that the host has not read yet."""
        try:
            return struct.unpack("i", fcntl.ioctl(self._slave, termios.FIONREAD, b"\0\0\0\0"))[0]
        except OSError:
            return 0

    def _drain(
        self, timeout_s: float = 2.0, settle_s: float = 0.1, stall_s: float | None = None
    ) -> bool:
        """Wait until the host has read everything written so far: nothing pending for
        ``settle_s`` on end, as bytes still in the pty's flip buffer are not yet counted as
        pending. Gives up after ``timeout_s``, or after ``stall_s`` in which the host read
        nothing (it is gone or stopped reading), or when the host sends STOP; True if drained."""
        start = time.monotonic()
        deadline = start + timeout_s
        empty_since = None
        last_pending, progress_at = self._pending_bytes(), start
        while time.monotonic() < deadline:
            pending = self._pending_bytes()
            now = time.monotonic()
            if pending > 0:
                empty_since = None
                if pending < last_pending:
                    progress_at = now
                last_pending = pending
                if stall_s is not None and now - progress_at >= stall_s:
                    self.drain_end = f"the host read nothing for {stall_s:g} s"
                    return False
            elif empty_since is None:
                empty_since = now
            elif now - empty_since >= settle_s:
                self.drain_end = f"read: nothing pending for {settle_s:g} s"
                return True
            if stall_s is not None and TYPE_STOP in self._read_host():
                self.stopped = True
                self.drain_end = "the host sent STOP"
                return False
            time.sleep(0.005)
        self.drain_end = f"gave up after {timeout_s:g} s"
        return False

    def _read_host(self) -> list[int]:
        """Packet types the host sent since the last call (a PARAMS is kept as asked for)."""
        try:
            data = os.read(self._master, 4096)  # type: ignore[arg-type]
        except (BlockingIOError, OSError):
            return []
        types = []
        for t, payload in self._parser.feed(data):
            if t == TYPE_PARAMS:
                self.asked = payload.decode("utf-8", "replace")
            types.append(t)
        return types

    def _wait_for_start(self, deadline: float) -> bool:
        while time.monotonic() < deadline:
            if TYPE_START in self._read_host():
                return True
            time.sleep(0.01)
        return False

    def _model_spec(self) -> str:
        """What this robot runs: its fixed model, else the host's PARAMS (older firmware
        ignores PARAMS), else the AVDM."""
        if self.emu.fixed_model:
            return self.emu.fixed_model
        if self.asked and not self.emu.silent:
            return self.asked
        return "avdm"

    def announcement(self, model) -> Announcement:
        """The ANNOUNCE this robot sends for ``model`` on its camera."""
        ctx = self.sim.camera.model_context()
        return Announcement(
            model=self.spec,
            outputs=tuple((o.name, o.unit) for o in model.outputs),
            fps=float(ctx["fps"]),
            width_px=int(ctx["width_px"]),
            height_px=int(ctx["height_px"]),
            deg_per_px=float(ctx["deg_per_px"]),
            texture_row=int(ctx["texture_row"]),
        )

    def _announce(self, model) -> None:
        if not self.emu.silent:
            self._write(encode_announce(self.announcement(model)))

    # -- the run ----------------------------------------------------------------------------
    def run(self, wait_for_host_s: float = 60.0, announce=None) -> dict:
        sim = self.sim
        shape = (sim.camera.height_px, sim.camera.width_px)
        self._parser = PacketParser()
        self.asked = ""
        self.stopped = False  # the host sent STOP
        self.drain_end = ""  # how the last wait for the host to read ended
        # warm up (compile) a model now, so that the one the host asks for is built, and
        # announced, soon after its START, as a firmware would
        make_model(self.emu.fixed_model or "avdm", **sim.camera.model_context())
        name = self.open_port()
        if announce is not None:
            announce(name)
        if not self._wait_for_start(time.monotonic() + wait_for_host_s):
            self.close_port()
            raise TimeoutError("no host sent START")
        self.spec = self._model_spec()
        try:
            model = make_model(self.spec, **sim.camera.model_context())
            self.spec = canonical_name(self.spec)
        except ValueError as exc:  # a robot cannot run what it does not know: it says nothing
            self._finish()
            raise UserError(f"the host asked for a model this robot cannot run: {exc}") from None
        self.report["model"] = self.spec
        self._model = model
        self._announce(model)
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
                    if not np.isnan(disconnect_at) and f >= disconnect_at * sim.camera.fps:
                        disconnect_at = float("nan")
                        self._disconnect(batch, outputs, i)
                    if not self.stopped and TYPE_STOP in self._read_host():
                        self.stopped = True  # END goes out, but no wait for a host that left
                    if self.stopped:
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
                    kind = "corrupted" if corrupt else "intact"
                    self.report[kind].append(f)
                    self._sent.append((f, len(packet), kind))
                    if not self._write(bytes(packet)):
                        self.report[kind].pop()
                        if self.stopped:
                            self._finish()
                            return self.report
                        break
        self._finish()
        return self.report

    def _disconnect(self, batch, outputs, i: int) -> None:
        """Close the port, stay away for reconnect_after_s, reopen behind the same link."""
        self.report["disconnects"] += 1
        self._drain()  # what was sent before the cable "comes out" reaches the host
        unread = self._pending_bytes()
        self.close_port()
        lost_unread = []  # frames the host had not read when the cable "came out"
        while unread > 0 and self._sent:
            f, size, kind = self._sent.pop()
            self.report[kind].remove(f)
            lost_unread.append(f)
            unread -= size
        gone = time.monotonic()
        frames_away = round(self.emu.reconnect_after_s * self.sim.camera.fps)
        first = int(batch.frame[i])
        self._lost = set(range(first, first + frames_away))
        self.report["lost_in_disconnect"] = sorted(self._lost | set(lost_unread))
        time.sleep(max(0.0, self.emu.reconnect_after_s - (time.monotonic() - gone)))
        self._parser = PacketParser()
        self.open_port()
        if self._wait_for_start(time.monotonic() + 30.0):
            self._announce(self._model)  # the firmware announces after every START

    def _finish(self) -> None:
        """END, then the port closes once the host has read it: closing the pty discards what
        the host has not read, and a host that misses END takes the closed port for a cable
        pulled out and waits for the robot to come back. Done when the host answers END with
        its STOP (vdc's host always does); without it, after 30 s with nothing left unread (a
        host that does not answer), 60 s in which the host read nothing (it is gone), or 5
        minutes in all."""
        if self._write(encode(TYPE_END)) and not self.stopped:
            # an empty queue alone is not proof that END was handled: a host reads ahead of
            # what it has processed, and bytes still in the pty's flip buffer are not
            # counted yet; the host's STOP is the proof (CI's two closes under a waiting host
            # were the host's own fault: it dropped packets read together, END among them)
            self._drain(timeout_s=300.0, settle_s=30.0, stall_s=60.0)
            self.report["end"] = self.drain_end
        self.close_port()
        if self.report_path is not None:
            self.report_path.write_text(json.dumps(self.report), encoding="utf-8")


@dataclasses.dataclass(frozen=True)
class EmulateSettings(Settings):
    """``vdc-capture emulate-robot`` as a settings object (one field per flag, same names)."""

    link: str = option("/tmp/vdc-robot", "stable path (symlink) to the emulated port")
    tf_hz: float = option(0.0, "wall TF, Hz", range=AT_LEAST_0)
    minutes: float = option(1.0, "run length", range=POSITIVE)
    seed: int = option(0, "random seed", range=AT_LEAST_0)
    model: str | None = option(
        None,
        "run this model on board whatever the host asks for (any model, a plug-in too); "
        "default: the model the host's PARAMS asks for, as the firmware does",
    )
    silent: bool = option(
        False,
        "play older firmware: ignore PARAMS, run --model (default avdm) and never announce",
    )
    fps: float = option(33.0, "the robot camera's frame rate, Hz", range=POSITIVE)
    width_px: int = option(99, "the robot camera's width, px (at most 255)", range=between(2, 255))
    height_px: int = option(
        72, "the robot camera's height, px (at most 255)", range=between(1, 255)
    )
    hfov_deg: float = option(
        70.0,
        "the robot camera's horizontal field of view, deg",
        range=between(0, 360, lo_open=True),
    )
    corrupt_rate: float = option(
        0.0,
        "share of packets corrupted, e.g. 0.01 (1-3 bits flipped in each)",
        range=FRACTION,
    )
    drop_rate: float = option(0.0, "probability of dropping each packet", range=FRACTION)
    disconnect_after: float | None = option(
        None,
        "close the port once, at this robot time after START (s): at the same frame whatever "
        "the load",
        range=POSITIVE,
    )
    reconnect_after: float = option(1.0, "seconds until the port reappears", range=POSITIVE)
    decimation: int = option(
        1, "send the image with every Nth frame (slow links)", range=AT_LEAST_1
    )
    fast: bool = option(False, "do not pace frames at the camera rate")
    wait: float = option(60.0, "seconds to wait for the host", range=POSITIVE)
    report: str | None = option(None, "write what was injected to this JSON file")


def report_line(report: dict) -> str:
    """The emulator's run in one line: what it sent, lost, and how its port closed."""
    return (
        f"sent {len(report['intact'])} intact and {len(report['corrupted'])} corrupted "
        f"frames; dropped {len(report['dropped'])}; {len(report['lost_in_disconnect'])} "
        f"lost in {report['disconnects']} disconnect(s)"
        + (f"; the port closed once {report['end']}" if report.get("end") else "")
    )


def emulate_robot(settings: EmulateSettings, announce: Callable[[str], None] | None = None) -> dict:
    """Run a simulated Colias-IV on a pseudo-terminal behind ``settings.link`` until its run
    ends; ``announce`` gets the pty's name once it exists. Returns what was injected (frames
    intact, corrupted, dropped, lost in disconnects). ValueError if no host sends START."""

    emu = EmulatorConfig(
        corrupt_rate=settings.corrupt_rate,
        drop_rate=settings.drop_rate,
        disconnect_after_s=settings.disconnect_after or float("nan"),
        reconnect_after_s=settings.reconnect_after,
        decimation=settings.decimation,
        realtime=not settings.fast,
        seed=settings.seed,
        fixed_model=settings.model or "",
        silent=settings.silent,
    )
    if not (settings.width_px <= 255 and settings.height_px <= 255):
        raise UserError("--width-px and --height-px are at most 255 (a FRAME's u8 fields).")
    if settings.model:
        make_model(settings.model)  # an unknown model fails before the port opens
    sim = SimConfig(
        wall=WallConfig(tf_schedule=((settings.tf_hz, settings.minutes * 60),)),
        camera=CameraConfig(
            width_px=settings.width_px,
            height_px=settings.height_px,
            fps=settings.fps,
            hfov_deg=settings.hfov_deg,
        ),
        duration_s=settings.minutes * 60,
        seed=settings.seed,
        model=settings.model or "avdm",
    )
    robot = RobotEmulator(
        sim, emu, Path(settings.link), Path(settings.report) if settings.report else None
    )
    try:
        return robot.run(wait_for_host_s=settings.wait, announce=announce)
    except TimeoutError as exc:
        raise UserError(str(exc)) from None
