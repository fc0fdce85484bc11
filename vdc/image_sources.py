"""Sources with no container (``vdc.sources.open_reader`` picks them): a camera by index,
read with OpenCV and stamped with the host's clock (:class:`CameraReader`), and numbered
images timed by their number and a frame rate (:class:`ImageSequenceReader`)."""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from vdc.errors import UserError
from vdc.source_frame import IMAGE_FORMAT, Reader, SourceFrame, grey_8bit


class CameraReader(Reader):
    """A camera by index, read with OpenCV and stamped with the host's clock."""

    def __init__(self, source: str, fps: float | None) -> None:
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
        self.cap = cv2.VideoCapture(int(source))
        if not self.cap.isOpened():
            raise UserError(f"camera {source} cannot be opened (no such camera).")
        ok, first = self.cap.read()
        if not ok or first is None:
            self.cap.release()
            raise UserError(f"camera {source} gives no frame.")
        self.first = first
        cam_fps = self.cap.get(cv2.CAP_PROP_FPS)
        self.fps = fps or (cam_fps if cam_fps and cam_fps > 0 else 30.0)
        h, w = first.shape[:2]
        self.info = {
            "kind": "camera",
            "codec": "camera",
            "nominal_fps": float(self.fps),
            "src_width_px": w,
            "src_height_px": h,
            "n_frames_header": 0,
            "rotation_deg": 0,
            "container_frames": None,  # live: no set length
            "first_frame_s": 0.0,
            **IMAGE_FORMAT,
        }

    def frames(self) -> Iterator[SourceFrame]:
        t0 = time.monotonic()
        img = self.first
        while img is not None:
            grey = _luma(img)
            yield SourceFrame(grey, time.monotonic() - t0, None, grey)
            ok, img = self.cap.read()
            img = img if ok else None

    def close(self) -> None:
        self.cap.release()


def _luma(img: np.ndarray) -> np.ndarray:
    return img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)


_PATTERN_FIELD = re.compile(r"%(0?)(\d*)d")


def _jpeg_cut(path: Path) -> bool:
    """A JPEG without its end-of-image marker was cut short (OpenCV decodes it anyway, with
    the missing part grey); trailing padding after the marker is allowed."""
    with path.open("rb") as fh:
        fh.seek(max(0, path.stat().st_size - 4096))
        tail = fh.read().rstrip(b"\x00")
    return not tail.endswith(b"\xff\xd9")


class ImageSequenceReader(Reader):
    """Numbered images (``frames/%05d.png``), timed by their number and ``fps``.

    Every number from the first file to the last is a frame: a missing number, a file that
    will not decode or a JPEG cut short is a lost frame, noted on the next good one (and so
    recorded as a dropped frame with its reason), never a silent end of the sequence."""

    def __init__(self, pattern: str, fps: float | None) -> None:
        if fps is None:
            raise UserError("an image sequence needs --fps (its frame rate).")
        fields = list(_PATTERN_FIELD.finditer(pattern))
        if len(fields) != 1:
            raise UserError(
                f"image sequence {pattern!r}: give one number field such as %05d "
                "(a file with % in its name is read as a video when it exists)."
            )
        field = fields[0]
        head, tail = pattern[: field.start()], pattern[field.end() :]
        folder_text, _, prefix = head.rpartition("/")
        folder, suffix = Path(folder_text or "."), tail
        number = re.compile(re.escape(prefix) + r"(\d+)" + re.escape(suffix) + "$")
        found: dict[int, Path] = {}
        if folder.is_dir():
            for entry in folder.iterdir():
                m = number.match(entry.name)
                if m and (not field.group(2) or len(m.group(1)) >= int(field.group(2))):
                    found.setdefault(int(m.group(1)), entry)
        if not found:
            raise UserError(f"image sequence {pattern!r} cannot be opened (no matching files).")
        width = f"{field.group(1)}{field.group(2)}d"
        self.name_of = lambda k: Path(head + format(k, width) + tail).name
        self.paths = found
        self.first_index, self.last_index = min(found), max(found)
        self.fps = float(fps)
        first = None
        for k in range(self.first_index, self.last_index + 1):  # the first readable image
            first = self._read(k)
            if first is not None:
                break
        if first is None:
            raise UserError(f"image sequence {pattern!r}: no image in it can be read.")
        self.problems, self.first_problem = 0, None  # counted again when the frames are read
        h, w = first.shape
        # a 16-bit image (PNG, TIFF) is measured at its 16 bits, full range (never as bytes)
        self.depth_dtype = first.dtype
        self.info = {
            "kind": "images",
            "codec": "image files",
            "nominal_fps": self.fps,
            "src_width_px": w,
            "src_height_px": h,
            "n_frames_header": self.last_index - self.first_index + 1,
            "rotation_deg": 0,
            # every number from the first file to the last is a frame
            "container_frames": self.last_index - self.first_index + 1,
            "first_frame_s": 0.0,
            **IMAGE_FORMAT,
            "bit_depth": 8 * first.dtype.itemsize,
        }
        self.size = (h, w)

    def _read(self, k: int) -> np.ndarray | None:
        path = self.paths.get(k)
        if path is None:
            return None
        if path.suffix.lower() in (".jpg", ".jpeg") and _jpeg_cut(path):
            return None
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None or img.ndim not in (2, 3):
            return None
        if img.dtype not in (np.uint8, np.uint16):  # 8- or 16-bit images only
            return None
        if img.ndim == 3 and img.shape[2] == 4:
            img = img[:, :, :3]
        return _luma(img)

    def frames(self) -> Iterator[SourceFrame]:
        note: list[str] = []
        k0: int | None = None  # the first image read: time 0
        for k in range(self.first_index, self.last_index + 1):
            img = self._read(k)
            path = self.paths.get(k)
            why = (
                None
                if img is not None and img.shape == self.size and img.dtype == self.depth_dtype
                else "missing"
                if path is None
                else "of another size"
                if img is not None and img.shape != self.size
                else "of another bit depth"
                if img is not None
                else "unreadable or cut short"
            )
            if why is not None:
                name = path.name if path is not None else self.name_of(k)
                note.append(self._problem(f"image {name} {why}"))
                continue
            if k0 is None:  # the first image read: those before it are lost
                k0 = k
                self.lost_before_first = k - self.first_index
                self.info["first_frame_s"] = self.lost_before_first / self.fps
            assert img is not None and path is not None
            size = path.stat().st_size  # the image file: its codec's bits
            grey = img if img.dtype == np.uint8 else grey_8bit(img)
            yield SourceFrame(grey, (k - k0) / self.fps, "; ".join(note) or None, img, size)
            note = []
