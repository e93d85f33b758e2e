"""Frame readers (the I/O half of the source stage): image folders, video files, MCAP
recordings and the synthetic scene. Each yields :class:`~stages.source.RawFrame` objects;
a frame that cannot be decoded is yielded with ``image=None`` and the reason, so the
source stage can report it and the stream goes on.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from gflow_core.synthetic import SyntheticScene
from stages.messages import Frame, MessageError, decode
from stages.source import RawFrame, SourceParams

__all__ = ["open_reader", "IMAGE_EXTENSIONS", "count_frames", "folder_frames"]

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp")


def _folder_files(path: Path) -> list[Path]:
    if not path.is_dir():
        raise FileNotFoundError(f"image folder not found: {path}")
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS)
    if not files:
        raise FileNotFoundError(f"no images ({', '.join(IMAGE_EXTENSIONS)}) in {path}")
    return files


def _indexed(files: list[Path]) -> list[tuple[int, Path | None]]:
    """Frame index of each file: its number when every name is a number (000017.jpg -> 17),
    so a file missing from the middle of the folder is a gap, not a shift; else the position."""
    stems = [f.stem for f in files]
    if all(s.isdigit() for s in stems):
        by_index = {int(s): f for s, f in zip(stems, files)}
        first, last = min(by_index), max(by_index)
        return [(i, by_index.get(i)) for i in range(first, last + 1)]
    return list(enumerate(files))


def folder_frames(path: str | os.PathLike) -> list[tuple[int, Path | None]]:
    """(frame index, image file or None where the file is missing) of an image folder, as the
    source stage numbers them."""
    return _indexed(_folder_files(Path(path)))


def _read_folder(files: list[Path], start: int, stop: int | None) -> Iterator[RawFrame]:
    for i, f in _indexed(files):
        if i < start or (stop is not None and i >= stop):
            continue
        if f is None:
            yield RawFrame(i, None, f"image file for frame {i} is missing from the folder", name=f"#{i}")
            continue
        try:
            data = np.fromfile(f, dtype=np.uint8)
        except OSError as e:
            yield RawFrame(i, None, f"cannot read {f.name}: {e.strerror}", name=f.name)
            continue
        img = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
        if img is None:
            yield RawFrame(i, None, f"{f.name} is not a decodable image ({data.size} bytes)", name=f.name)
        else:
            yield RawFrame(i, img, name=f.name)


def _read_video(path: Path, start: int, stop: int | None) -> Iterator[RawFrame]:
    if not path.is_file():
        raise FileNotFoundError(f"video file not found: {path}")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise ValueError(f"OpenCV cannot open {path} as a video")
    expected = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    try:
        i = 0
        while stop is None or i < stop:
            ok, img = cap.read()
            if not ok:
                if expected > 0 and i < expected and (stop is None or i < stop):
                    # a truncated or corrupt file: say so once, then end the stream cleanly
                    yield RawFrame(i, None, f"{path.name}: video ends at frame {i} but its header says {expected} "
                                            f"frames (truncated or corrupt file)", name=f"{path.name}#{i}")
                break
            if i >= start:
                yield RawFrame(i, img, name=f"{path.name}#{i}")
            i += 1
    finally:
        cap.release()


def _read_mcap(path: Path, start: int, stop: int | None) -> Iterator[RawFrame]:
    from pipeline.io.mcap_io import iter_records

    for rec in iter_records(path):
        if not rec.topic.endswith("/frames"):
            continue
        try:
            msg = decode(rec.data)
        except MessageError:
            continue
        if not isinstance(msg, Frame):
            continue
        s = msg.header.seq
        if s < start or (stop is not None and s >= stop):
            continue
        try:
            yield RawFrame(s, msg.image.array(), truth=msg.truth, name=msg.source)
        except MessageError as e:
            yield RawFrame(s, None, str(e), name=msg.source)


def _read_synthetic(p: SourceParams) -> Iterator[RawFrame]:
    scene = SyntheticScene(width=p.width, height=p.height, n_frames=p.frames, seed=p.scene_seed, noise=p.noise)
    stop = p.frames if p.stop is None else min(p.stop, p.frames)
    for t in range(p.start, stop):
        yield RawFrame(t, scene.render(t), truth=scene.truth_box(t), name=f"synthetic#{t}")


def open_reader(p: SourceParams, base_dir: str | os.PathLike = ".") -> Iterator[RawFrame]:
    """An iterator of decoded frames for the source parameters. Paths are relative to ``base_dir``."""
    path = Path(base_dir, p.path) if p.path else Path(".")
    if p.kind == "synthetic":
        return _read_synthetic(p)
    if p.kind == "folder":
        return _read_folder(_folder_files(path), p.start, p.stop)
    if p.kind == "video":
        return _read_video(path, p.start, p.stop)
    if p.kind == "mcap":
        if not path.is_file():
            raise FileNotFoundError(f"MCAP file not found: {path}")
        return _read_mcap(path, p.start, p.stop)
    raise ValueError(f"unknown source kind {p.kind!r}")


def count_frames(p: SourceParams, base_dir: str | os.PathLike = ".") -> int | None:
    """Number of frames the source will produce, when it can be known cheaply."""
    if p.kind == "synthetic":
        n = p.frames
    elif p.kind == "folder":
        n = len(_indexed(_folder_files(Path(base_dir, p.path))))
    elif p.kind == "video":
        cap = cv2.VideoCapture(str(Path(base_dir, p.path)))
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 0
        cap.release()
        if n <= 0:
            return None
    else:
        return None
    stop = n if p.stop is None else min(n, p.stop)
    return max(0, stop - p.start)
