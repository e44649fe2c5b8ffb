"""Image and label-map file I/O (OpenCV), with one-line errors that name the file.

* Colour images are returned as ``uint8 [H, W, 3]`` **RGB** (OpenCV reads BGR; the flip happens here only).
* Label maps (semantic, instance) are 8- or 16-bit single-channel PNGs holding exact integer ids.
* COCO panoptic PNGs encode a segment id as ``R + 256 G + 256² B`` (:func:`rgb_to_id` / :func:`id_to_rgb`).
"""

from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile
import threading
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from lift3d.errors import InputError
from lift3d.utils.atomic import write_bytes_atomic


def rgb_to_id(rgb: np.ndarray) -> np.ndarray:
    """COCO panoptic colour → segment id: ``R + 256 G + 256² B``.

    Parameters
    ----------
    rgb : np.ndarray
        ``[..., 3]`` uint8 RGB.

    Returns
    -------
    np.ndarray
        ``[...]`` int64 segment ids (0 = void).

    Examples
    --------
    >>> import numpy as np
    >>> int(rgb_to_id(np.array([1, 2, 3], np.uint8)))
    197121
    """
    rgb = np.asarray(rgb).astype(np.int64)
    return rgb[..., 0] + 256 * rgb[..., 1] + 256 * 256 * rgb[..., 2]


def id_to_rgb(ids: np.ndarray) -> np.ndarray:
    """Segment id → COCO panoptic colour (inverse of :func:`rgb_to_id`), ``uint8 [..., 3]``."""
    ids = np.asarray(ids, dtype=np.int64)
    if ids.size and (ids.min() < 0 or ids.max() >= 256**3):
        raise ValueError("panoptic segment ids must lie in [0, 256^3)")
    return np.stack([ids % 256, (ids // 256) % 256, ids // 65536], -1).astype(np.uint8)


_DECODE_LOCK = threading.Lock()
# OpenCV's own log prefix: "[ WARN:0@0.055] global grfmt_png.cpp:793 readFromStreamOrBuffer ".
_CV_LOG_PREFIX = re.compile(r"^\[\s*[A-Z]+:\d+@[\d.]+\]\s+(global\s+)?\S+:\d+\s+\S+\s+")


@contextlib.contextmanager
def _native_stderr_captured() -> Iterator[list[str]]:
    """Collect what the C decoders print straight onto file descriptor 2 while decoding.

    libpng (``libpng error: IHDR: CRC error``), libjpeg (``Corrupt JPEG data: ...``) and OpenCV's logger
    (``[ WARN:0@0.1] global grfmt_png.cpp:793 ... PNG input buffer is incomplete``) write there directly,
    which would break the CLI's one-line error on a corrupt file. The captured lines (prefixes stripped) are
    returned in the yielded list once the block ends, so the caller can put them into its own message."""
    lines: list[str] = []
    with _DECODE_LOCK:
        try:
            sink = tempfile.TemporaryFile()
        except OSError:  # no writable temp folder: decode without capturing rather than fail
            yield lines
            return
        try:
            saved = os.dup(2)
        except OSError:  # no stderr at all (a daemon): nothing to capture
            sink.close()
            yield lines
            return
        try:
            with contextlib.suppress(Exception):
                sys.stderr.flush()  # Python's own pending output goes where it was meant to
            os.dup2(sink.fileno(), 2)
            yield lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            text = sink.read(4096).decode("utf-8", errors="replace")
            sink.close()
            for line in text.splitlines():
                line = _CV_LOG_PREFIX.sub("", line.strip())
                if line and line not in lines:
                    lines.append(line)


def _imread(path: Path, flags: int) -> np.ndarray:
    if not path.is_file():
        raise InputError(path, "file not found")
    try:
        data = np.fromfile(str(path), dtype=np.uint8)
    except OSError as exc:
        raise InputError(path, f"cannot be read ({exc.strerror or exc})") from exc
    with _native_stderr_captured() as diagnostics:
        img = cv2.imdecode(data, flags) if data.size else None
    detail = "; ".join(diagnostics)[:200]
    if img is None:
        what = "empty file" if not data.size else "corrupt or truncated?"
        raise InputError(path, f"not a readable image ({what}{': ' + detail if detail else ''})")
    if detail:
        # Decoded, but the decoder had to patch over damage (typically a corrupt JPEG): say so once.
        print(f"lift3d: warning: {path}: decoded with errors ({detail})", file=sys.stderr)
    return img


def read_rgb(path: str | Path) -> np.ndarray:
    """Read a colour image as ``uint8 [H, W, 3]`` RGB (16-bit images are scaled to 8 bit, alpha dropped)."""
    path = Path(path)
    img = _imread(path, cv2.IMREAD_UNCHANGED)
    if img.dtype == np.uint16:
        img = (img // 257).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise InputError(path, f"unsupported image dtype {img.dtype}")
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=-1)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    else:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return np.ascontiguousarray(img)


def read_label_map(path: str | Path) -> np.ndarray:
    """Read a single-channel 8/16-bit PNG of integer ids as ``int32 [H, W]``."""
    path = Path(path)
    img = _imread(path, cv2.IMREAD_UNCHANGED)
    if img.ndim == 3:
        # A label PNG saved as RGB with equal channels is still unambiguous.
        if not (np.array_equal(img[..., 0], img[..., 1]) and np.array_equal(img[..., 1], img[..., 2])):
            raise InputError(path, "label map must be single-channel (got colour)")
        img = img[..., 0]
    if img.dtype not in (np.uint8, np.uint16):
        raise InputError(path, f"label map must be 8- or 16-bit integers (got {img.dtype})")
    return img.astype(np.int32)


def read_unit_map(path: str | Path) -> np.ndarray:
    """Read an 8- or 16-bit single-channel PNG of values in [0, 1] (e.g. a confidence map) as
    ``float32 [H, W]``: 8-bit images are divided by 255, 16-bit ones by 65535.

    The scale comes from the file's bit depth, not from its values: a 16-bit map whose values all happen
    to be ≤ 255 (a low-confidence frame) is still a 16-bit map."""
    path = Path(path)
    img = _imread(path, cv2.IMREAD_UNCHANGED)
    if img.ndim != 2:
        raise InputError(path, "must be a single-channel 8- or 16-bit image")
    if img.dtype == np.uint8:
        return img.astype(np.float32) / np.float32(255.0)
    if img.dtype == np.uint16:
        return img.astype(np.float32) / np.float32(65535.0)
    raise InputError(path, f"must be an 8- or 16-bit image (got {img.dtype})")


def read_panoptic_png(path: str | Path) -> np.ndarray:
    """Read a COCO panoptic PNG as ``int64 [H, W]`` segment ids (0 = void)."""
    path = Path(path)
    img = _imread(path, cv2.IMREAD_UNCHANGED)
    if img.ndim != 3 or img.shape[2] < 3 or img.dtype != np.uint8:
        raise InputError(path, "a COCO panoptic PNG must be 8-bit RGB")
    return rgb_to_id(cv2.cvtColor(img[..., :3], cv2.COLOR_BGR2RGB))


def read_depth(path: str | Path, unit_scale: float) -> np.ndarray:
    """Read a depth image (uint16 in ``unit_scale`` metres per unit, 0 = unknown; or float32, as TIFF) as float32
    metres. ``.npy`` float arrays in metres are accepted too. Unknown is 0 whatever the file said: 0, NaN, ±inf
    (what float formats write for no return) or a negative marker.

    Examples
    --------
    >>> import tempfile
    >>> path = Path(tempfile.mkdtemp()) / "d.npy"
    >>> np.save(path, np.array([[1.5, np.nan, np.inf, -1.0]], np.float32))
    >>> read_depth(path, 1.0).tolist()
    [[1.5, 0.0, 0.0, 0.0]]
    """
    path = Path(path)
    if path.suffix == ".npy":
        try:
            d = np.load(path).astype(np.float32)
        except (OSError, ValueError) as exc:
            raise InputError(path, f"not a readable .npy depth ({exc})") from exc
    else:
        img = _imread(path, cv2.IMREAD_UNCHANGED)
        if img.ndim != 2:
            raise InputError(path, "depth must be a single-channel image")
        d = img.astype(np.float32) * np.float32(unit_scale)
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(d) & (d > 0), d, np.float32(0.0)).astype(np.float32, copy=False)


def _encode_png(path: Path, img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise InputError(path, "PNG encoding failed")
    return buf.tobytes()


def write_rgb(path: str | Path, rgb: np.ndarray, quality: int = 95) -> None:
    """Write ``uint8 [H, W, 3]`` RGB as PNG or JPEG (by suffix), atomically."""
    path = Path(path)
    bgr = cv2.cvtColor(np.ascontiguousarray(rgb, dtype=np.uint8), cv2.COLOR_RGB2BGR)
    if path.suffix.lower() in (".jpg", ".jpeg"):
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, quality])
        if not ok:
            raise InputError(path, "JPEG encoding failed")
        write_bytes_atomic(path, buf.tobytes())
    else:
        write_bytes_atomic(path, _encode_png(path, bgr))


def write_label_map(path: str | Path, labels: np.ndarray) -> None:
    """Write integer ids ``[H, W]`` as a 16-bit PNG (exact ids 0..65535), atomically."""
    path = Path(path)
    labels = np.asarray(labels)
    if labels.size and (labels.min() < 0 or labels.max() > 65535):
        raise ValueError(f"{path}: label ids must lie in [0, 65535] for a 16-bit PNG")
    write_bytes_atomic(path, _encode_png(path, labels.astype(np.uint16)))


def write_panoptic_png(path: str | Path, segment_ids: np.ndarray) -> None:
    """Write segment ids ``[H, W]`` as a COCO panoptic RGB PNG, atomically."""
    path = Path(path)
    rgb = id_to_rgb(segment_ids)
    write_bytes_atomic(path, _encode_png(path, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)))


def write_depth(path: str | Path, depth_m: np.ndarray, unit_scale: float) -> None:
    """Write metric depth as uint16 PNG in units of ``unit_scale`` metres (0 = unknown / out of range)."""
    path = Path(path)
    d = np.asarray(depth_m, np.float64) / unit_scale
    d = np.where(np.isfinite(d) & (d > 0) & (d < 65535.5), np.round(d), 0).astype(np.uint16)
    write_bytes_atomic(path, _encode_png(path, d))
