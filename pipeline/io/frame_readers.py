"""Frame readers (the I/O half of the source stage): image folders, video files, MCAP
recordings, the synthetic scene and live sources (:mod:`pipeline.io.live_capture`). Each
yields :class:`~stages.source.RawFrame` objects;
a frame that cannot be decoded is yielded with ``image=None`` and the reason, so the
source stage can report it and the stream goes on.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Generator, Iterator, TypedDict

import cv2
import numpy as np

from gflow_core.synthetic import SyntheticScene
from gflow_msgs.messages import Capture, Frame, MessageError, decode
from stages.source import RawFrame, SourceParams

from pipeline.io.decoder_messages import decoder_messages
from pipeline.io.live_capture import LiveCapture
from pipeline.io.path_errors import MissingPath

__all__ = ["open_reader", "open_live", "read_live", "IMAGE_EXTENSIONS", "count_frames", "folder_frames"]

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp")


def _folder_files(path: Path) -> list[Path]:
    if not path.is_dir():
        raise MissingPath(f"image folder not found: {path}")
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS)
    if not files:
        raise MissingPath(f"no images ({', '.join(IMAGE_EXTENSIONS)}) in {path}")
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
        with decoder_messages() as said:
            img = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
        why = f" ({said[0]})" if said else ""
        if img is None:
            yield RawFrame(i, None, f"{f.name} is not a decodable image ({data.size} bytes){why}", name=f.name)
        elif said:  # decoded whole, from damaged data: tracked as decoded (as a live stream's damaged frames are)
            yield RawFrame(i, img, name=f.name, events=(("damaged_input", (
                f"frame {i} ({f.name}) decoded from damaged data{why}; tracked as decoded")),))
        else:
            yield RawFrame(i, img, name=f.name)


def _read_video(path: Path, start: int, stop: int | None) -> Iterator[RawFrame]:
    if not path.is_file():
        raise MissingPath(f"video file not found: {path}")
    with decoder_messages() as said:
        cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise ValueError(f"OpenCV cannot open {path} as a video" + (f" ({said[0]})" if said else ""))
    expected = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    try:
        i = 0
        while stop is None or i < stop:
            with decoder_messages() as said:  # FFmpeg's decoder reports a frame it could not decode whole
                ok, img = cap.read()
            why = f" ({said[0]})" if said else ""
            if not ok:
                if expected > 0 and i < expected and (stop is None or i < stop):
                    # a truncated or corrupt file: say so once, then end the stream cleanly
                    yield RawFrame(i, None, f"{path.name}: video ends at frame {i} but its header says {expected} "
                                            f"frames (truncated or corrupt file){why}", name=f"{path.name}#{i}")
                break
            if i >= start:
                yield RawFrame(i, img, name=f"{path.name}#{i}", events=(("damaged_input", (
                    f"frame {i} of {path.name} decoded from damaged data{why}; tracked as decoded")),) if said else ())
            i += 1
    finally:
        cap.release()


def _recorded_captures(path: Path) -> tuple[dict[int, Capture], dict[int, tuple[int, np.ndarray]]]:
    """A live run's Capture messages, {seq: Capture}, and the skipped frames it recorded,
    {camera frame: (stamp, image)}."""
    from pipeline.io.mcap_io import iter_records

    captures, skipped = {}, {}
    for rec in iter_records(path, on_truncated=lambda text: None):  # damage: said by _read_mcap
        if rec.type == "Capture" and rec.topic.endswith("/captures"):
            try:
                c = decode(rec.data)
            except MessageError:
                continue
            if isinstance(c, Capture):
                captures[c.header.seq] = c
        elif rec.type == "Frame" and rec.topic.endswith("/skipped"):
            try:
                f = decode(rec.data)
                skipped[f.header.seq] = (f.header.stamp_ns, f.image.array())
            except (MessageError, AttributeError):
                continue
    return captures, skipped


class _LiveFields(TypedDict, total=False):
    """What a recorded live run adds to a :class:`RawFrame` (its keywords)."""

    frame: int
    stamp_ns: int
    skipped: int
    gap_s: float
    skipped_frames: tuple[tuple[int, int, np.ndarray], ...]
    missed: int
    damaged: bool


def _read_mcap(path: Path, start: int, stop: int | None, host_clock: bool = False) -> Iterator[RawFrame]:
    """The recorded frames; with ``host_clock``, with their recorded stamps and what the live
    source said about each (its Capture, and the skipped frames recorded before it), so a live
    run re-runs as it was tracked. A recording damaged inside (a record that cannot be read with more
    of the file after it) ends with a frame with no image whose ``events`` say so (``damaged_input``)."""
    from pipeline.io.mcap_io import Damaged, iter_records

    captures, skipped = _recorded_captures(path) if host_clock else ({}, {})
    prev_frame = last = -1
    damage: list[str] = []  # what iter_records says of a record that failed with more of the file after it
    for rec in iter_records(path, on_truncated=lambda text: damage.append(text) if isinstance(text, Damaged) else None):
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
        c = captures.get(s)
        frame = c.frame if c is not None else -1
        kept = tuple((f, *skipped[f]) for f in sorted(skipped) if prev_frame < f < frame)
        prev_frame = max(prev_frame, frame)
        live: _LiveFields = (_LiveFields(frame=frame, stamp_ns=msg.header.stamp_ns, skipped_frames=kept,
                                         skipped=c.skipped if c else 0, gap_s=c.gap_s if c else 0.0,
                                         missed=c.missed if c else 0, damaged=c.damaged if c else False)
                             if host_clock else {})
        last = s
        try:
            yield RawFrame(s, msg.image.array(), truth=msg.truth, name=msg.source, **live)
        except MessageError as e:
            yield RawFrame(s, None, str(e), name=msg.source, **live)
    if damage:  # the frames after the damage are lost: the source stage reports it (one line, every way it runs)
        yield RawFrame(max(last + 1, start), None, events=(("damaged_input", str(damage[0])),))


def _read_synthetic(p: SourceParams) -> Iterator[RawFrame]:
    scene = SyntheticScene(width=p.width, height=p.height, n_frames=p.frames, seed=p.scene_seed, noise=p.noise)
    stop = p.frames if p.stop is None else min(p.stop, p.frames)
    for t in range(p.start, stop):
        yield RawFrame(t, scene.render(t), truth=scene.truth_box(t), name=f"synthetic#{t}")


def read_live(capture: LiveCapture, p: SourceParams, first_seq: int = 0) -> Generator[RawFrame, None, None]:
    """The frames of an open live capture, numbered ``first_seq``, ``first_seq`` + 1, ... as they are
    taken (each the newest decoded when the caller asks for it); a last frame with no image
    carries the reports of the stream's end. Closes the capture when done."""
    try:
        seq = first_seq
        while True:
            f = capture.take()
            if f is None:
                break
            kept = tuple((c.frame, c.stamp_ns, c.image) for c in f.skipped_frames if c.image is not None)
            yield RawFrame(seq, f.image, name=f"{p.path}#{f.frame}", frame=f.frame, stamp_ns=f.stamp_ns,
                           skipped=f.skipped, gap_s=f.gap_s, skipped_frames=kept, events=f.events, missed=f.missed,
                           damaged=f.damaged)
            seq += 1
        events = capture.pending_events() + ([("stream_ended", capture.ended)] if capture.ended else [])
        if events:
            yield RawFrame(seq, None, events=tuple(events))
    finally:
        capture.close()


def open_live(p: SourceParams) -> LiveCapture:
    """Open the live source of ``p`` (raises :class:`LiveSourceError` in one line)."""
    return LiveCapture(p.path, fps=p.fps, open_timeout=p.open_timeout, reconnect=p.reconnect,
                       keep_skipped=p.keep_skipped, stop=p.stop, url=p.relay, read_timeout=p.read_timeout).open()


def open_reader(p: SourceParams, base_dir: str | os.PathLike = ".") -> Iterator[RawFrame]:
    """An iterator of decoded frames for the source parameters. Paths are relative to ``base_dir``."""
    if p.kind == "live":
        return read_live(open_live(p), p)
    path = Path(base_dir, p.path) if p.path else Path(".")
    if p.kind == "synthetic":
        return _read_synthetic(p)
    if p.kind == "folder":
        return _read_folder(_folder_files(path), p.start, p.stop)
    if p.kind == "video":
        return _read_video(path, p.start, p.stop)
    if p.kind == "mcap":
        if not path.is_file():
            raise MissingPath(f"MCAP file not found: {path}")
        return _read_mcap(path, p.start, p.stop, p.host_clock)
    raise ValueError(f"unknown source kind {p.kind!r}")


def count_frames(p: SourceParams, base_dir: str | os.PathLike = ".") -> int | None:
    """Number of frames the source will produce, when it can be known cheaply."""
    if p.kind == "synthetic":
        n = p.frames
    elif p.kind == "folder":
        n = len(_indexed(_folder_files(Path(base_dir, p.path))))
    elif p.kind == "video":
        with decoder_messages():  # what FFmpeg says of a damaged file is said by the reader, not here
            cap = cv2.VideoCapture(str(Path(base_dir, p.path)))
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 0
        cap.release()
        if n <= 0:
            return None
    else:
        return None
    stop = n if p.stop is None else min(n, p.stop)
    return max(0, stop - p.start)
