"""Reading whole training sequences into memory (the I/O half of ``gflow learn``).

* :func:`read_frames`: an image folder (or a dataset folder holding ``frames/``) or a
  video file, through the same readers as the source stage (:mod:`pipeline.io.frame_readers`);
* :func:`read_avletters`: an AVLetters speaker file (``NAME.npz`` with ``frames`` (N, 60, 80)
  uint8, ``starts``, ``letters``, ``repetitions``), selecting utterances by repetition
  and letter. Each utterance is its own sequence, so dynamics are not learned across
  utterance boundaries.
* :func:`write_frames`: frames to a numbered PNG folder (a sequence ``gflow track`` reads).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Sequence

import cv2
import numpy as np

from stages.source import SourceParams

from pipeline.io.frame_readers import IMAGE_EXTENSIONS, open_reader
from pipeline.io.npz_files import read_npz
from pipeline.io.path_errors import MissingPath

__all__ = ["FrameSequence", "read_frames", "resolve_source", "AVLetters", "read_avletters", "select_utterances", "write_frames",
           "parse_range"]


@dataclass(frozen=True)
class FrameSequence:
    """Decoded frames in memory.

    frames : list of (H, W, 3) or (H, W) uint8 images.
    frame_index : (T,) int64, index of each frame in its source (sequence id ``sequence``).
    sequence : (T,) int64, sequence id of each frame (dynamics are learned within one).
    labels : (T,) str, optional per-frame label (the letter of an AVLetters utterance).
    skipped : list of (index, reason) for frames that could not be decoded.
    """

    frames: list[np.ndarray]
    frame_index: np.ndarray
    sequence: np.ndarray
    labels: np.ndarray | None = None
    skipped: tuple[tuple[int, str], ...] = ()

    def __len__(self) -> int:
        return len(self.frames)


def parse_range(text: str | None) -> tuple[int, int | None]:
    """``"A:B"`` (``"A:"``, ``":B"``, ``"A"`` = ``"A:A+1"``) -> (start, stop); None -> (0, None)."""
    if text is None or text.strip() in ("", ":"):
        return 0, None
    t = text.strip()
    try:
        if ":" not in t:
            a = int(t)
            return a, a + 1
        a_s, b_s = t.split(":", 1)
        a = int(a_s) if a_s.strip() else 0
        b = int(b_s) if b_s.strip() else None
    except ValueError:
        raise ValueError(f"frame range must look like A:B (e.g. 0:150), got {text!r}") from None
    if a < 0 or (b is not None and b <= a):
        raise ValueError(f"frame range needs 0 <= A < B, got {text!r}")
    return a, b


def resolve_source(source: str | os.PathLike) -> tuple[Literal["folder", "video", "avletters"], Path]:
    """("folder" | "video" | "avletters", path) for a training source path."""
    p = Path(source)
    if p.is_dir():
        if (p / "frames").is_dir() and not any(q.suffix.lower() in IMAGE_EXTENSIONS for q in p.iterdir()):
            p = p / "frames"  # a dataset folder like ../shared/data/caviar1
        return "folder", p
    if p.is_file():
        return ("avletters" if p.suffix.lower() == ".npz" else "video"), p
    raise MissingPath(f"training source not found: {source} (give an image folder, a dataset folder with "
                            "frames/, a video file or an AVLetters .npz)")


def read_frames(source: str | os.PathLike, start: int = 0, stop: int | None = None) -> FrameSequence:
    """Frames ``start <= index < stop`` of an image folder or a video file.

    Frames that cannot be decoded are left out (listed in ``skipped``); their index is
    missing from ``frame_index``, so no dynamics are learned across them.

    Raises
    ------
    FileNotFoundError
        The source does not exist or the folder holds no images.
    ValueError
        No frame could be decoded in the range.
    """
    kind, path = resolve_source(source)
    if kind == "avletters":
        raise ValueError(f"{path} is an .npz file; read it with read_avletters")
    params = SourceParams(kind=kind, path=str(path.resolve()), start=start, stop=stop)
    frames, index, skipped = [], [], []
    for raw in open_reader(params):
        if raw.image is None:
            skipped.append((raw.index, raw.error or "could not be decoded"))
            continue
        frames.append(raw.image)
        index.append(raw.index)
    if not frames:
        rng = f"{start}:{'' if stop is None else stop}"
        raise ValueError(f"no decodable frame in {path} for frames {rng}" +
                         (f" ({len(skipped)} could not be decoded)" if skipped else ""))
    return FrameSequence(frames=frames, frame_index=np.array(index, dtype=np.int64),
                         sequence=np.zeros(len(index), dtype=np.int64), skipped=tuple(skipped))


@dataclass(frozen=True)
class AVLetters:
    """One AVLetters speaker file."""

    frames: np.ndarray  # (N, 60, 80) uint8
    starts: np.ndarray  # (U,) int64
    letters: np.ndarray  # (U,) str
    repetitions: np.ndarray  # (U,) int64

    @property
    def ends(self) -> np.ndarray:
        return np.r_[self.starts[1:], self.frames.shape[0]].astype(np.int64)

    def letter_of_frame(self, index: np.ndarray) -> np.ndarray:
        """Letter of the utterance each frame index belongs to. (M,) int -> (M,) str."""
        u = np.searchsorted(self.starts, np.asarray(index, dtype=np.int64), side="right") - 1
        return self.letters[u]

    @classmethod
    def load(cls, path: str | os.PathLike) -> "AVLetters":
        p = Path(path)
        if not p.is_file():
            raise MissingPath(f"AVLetters file not found: {p}")
        arrays = read_npz(p, "AVLetters file")
        need = {"frames", "starts", "letters", "repetitions"}
        if not need <= set(arrays):
            raise ValueError(f"{p}: an AVLetters file needs arrays {sorted(need)}, got {sorted(arrays)}")
        _check_kinds(p, arrays)
        fr, st = arrays["frames"], arrays["starts"].astype(np.int64)
        let, rep = arrays["letters"].astype(str), arrays["repetitions"].astype(np.int64)
        if fr.ndim != 3 or fr.dtype != np.uint8:
            raise ValueError(f"{p}: frames must be (N, H, W) uint8, got {fr.dtype} {fr.shape}")
        if not (st.shape == let.shape == rep.shape) or st.ndim != 1 or st.size == 0:
            raise ValueError(f"{p}: starts, letters and repetitions must be 1-d arrays of one length")
        if st[0] != 0 or (np.diff(st) <= 0).any() or st[-1] >= fr.shape[0]:
            raise ValueError(f"{p}: utterance starts must increase from 0 within the {fr.shape[0]} frames")
        return cls(frames=fr, starts=st, letters=let, repetitions=rep)


#: the kind of number or text each array of an AVLetters file holds (numpy's dtype kinds), as the files are written
_AV_KINDS = {"starts": ("iu", "whole numbers"), "repetitions": ("iu", "whole numbers"), "letters": ("U", "text")}


def _check_kinds(p: Path, arrays: dict[str, np.ndarray]) -> None:
    """A ValueError naming ``p`` and the array when one holds another kind of value than :data:`_AV_KINDS` says:
    utterance starts of 0.5 were cut to whole frames without a word, repetitions of text failed naming no file."""
    for name, (kinds, what) in _AV_KINDS.items():
        if arrays[name].dtype.kind not in kinds:
            raise ValueError(f"{p}: {name} must be {what}, got {arrays[name].dtype}")


def _parse_letters(text: str | None) -> set[str] | None:
    if not text:
        return None
    out: set[str] = set()
    for part in text.upper().replace(" ", "").split(","):
        if "-" in part and len(part) == 3:
            a, b = part.split("-")
            out.update(chr(c) for c in range(ord(a), ord(b) + 1))
        elif len(part) == 1 and part.isalpha():
            out.add(part)
        else:
            raise ValueError(f"letters must look like A-Z or A,B,C, got {text!r}")
    return out


def read_avletters(path: str | os.PathLike, reps: Sequence[int] | None = None,
                   letters: str | None = None) -> tuple[FrameSequence, AVLetters]:
    """The utterances of an AVLetters speaker file with the given repetitions and letters.

    Returns the selected frames (``frame_index`` = index in the file's ``frames``,
    ``sequence`` = utterance number, ``labels`` = the letter) and the whole file.
    """
    av = AVLetters.load(path)
    return select_utterances(av, reps, letters, where=str(path)), av


def select_utterances(av: AVLetters, reps: Sequence[int] | None = None, letters: str | None = None,
                      where: str = "the AVLetters file") -> FrameSequence:
    """The frames of the utterances of ``av`` with the given repetitions and letters (as
    :func:`read_avletters`); a ValueError naming ``where`` when none is."""
    want = _parse_letters(letters)
    reps_set = None if reps is None else {int(r) for r in reps}
    ends = av.ends
    frames: list[np.ndarray] = []
    index: list[np.ndarray] = []
    seq: list[np.ndarray] = []
    labels: list[np.ndarray] = []
    for u in range(av.starts.size):
        if reps_set is not None and int(av.repetitions[u]) not in reps_set:
            continue
        if want is not None and str(av.letters[u]) not in want:
            continue
        idx = np.arange(av.starts[u], ends[u])
        frames.extend(av.frames[i] for i in idx)
        index.append(idx)
        seq.append(np.full(idx.size, u))
        labels.append(np.full(idx.size, str(av.letters[u])))
    if not frames:
        raise ValueError(f"{where}: no utterance with repetitions {sorted(reps_set) if reps_set else 'any'} and "
                         f"letters {letters or 'any'} (the file has repetitions {sorted(set(av.repetitions.tolist()))})")
    return FrameSequence(frames=frames, frame_index=np.concatenate(index), sequence=np.concatenate(seq),
                         labels=np.concatenate(labels))


def write_frames(folder: str | os.PathLike, frames: Sequence[np.ndarray], first: int = 0) -> Path:
    """Write frames as ``folder/NNNNNN.png`` (numbered from ``first``), for ``gflow track``."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    for i, f in enumerate(frames):
        if not cv2.imwrite(str(out / f"{first + i:06d}.png"), np.asarray(f)):
            raise OSError(f"could not write {out / f'{first + i:06d}.png'}")
    return out
