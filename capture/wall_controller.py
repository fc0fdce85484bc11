"""The optional LED wall controller of a robot capture: a line protocol on a second serial
port, told the wall TF in force whenever it changes (``vdc-capture robot --wall-port``)."""

from __future__ import annotations

import serial

from capture.config import WallConfig
from vdc.errors import UserError


class WallController:
    """Optional LED wall controller on a second serial port; a line protocol (ASCII, \\n):
    ``TF <hz> PERIOD <m> SCENE <grating|natural>`` whenever the TF in force changes."""

    def __init__(self, port: str, wall: WallConfig) -> None:
        try:
            self.ser = serial.Serial(port, 115200, timeout=0.1)
        except (serial.SerialException, OSError) as exc:
            raise UserError(
                f"cannot open the wall controller port {port!r}: "
                f"{getattr(exc, 'strerror', None) or exc}"
            ) from None
        self.wall = wall
        self.last: float | None = None

    def update(self, tf_hz: float) -> None:
        if tf_hz != self.last:
            line = f"TF {tf_hz:.3f} PERIOD {self.wall.drift_period_m:.4f} SCENE {self.wall.scene}\n"
            self.ser.write(line.encode("ascii"))
            self.ser.flush()
            self.last = tf_hz
