"""Sequences in the VOT toolkit's layout, and the workspace files around them (``gflow export vot``).

A VOT workspace (what ``vot evaluate --workspace W`` reads; vot-toolkit 0.9)::

    W/config.yaml                      stack: ./stack.yaml, registry: [./trackers.ini]
    W/stack.yaml                       the experiments and their analyses
    W/trackers.ini                     how to run each tracker (protocol trax, its command)
    W/sequences/list.txt               one sequence name a line
    W/sequences/NAME/sequence          key=value metadata: channels.color, width, height, length
    W/sequences/NAME/groundtruth.txt   one line a frame: x,y,w,h (0-based pixels, top-left corner)
    W/sequences/NAME/color/00000001.jpg ...   the frames, numbered from 1

Conventions (``docs/vot.md``):

* VOT frame 1 is the source's first frame with ground truth (where ``gflow benchmark`` starts),
  and the sequence runs to the folder's last frame; the ``sequence`` file records the source
  frame of VOT frame 1 as ``gflow.first_frame``.
* Frames are copied byte for byte when every file of the folder has one image format (so the
  toolkit hands a tracker the very pixels ``gflow track`` reads), else decoded as the source
  stage decodes them and written as PNG; ``channels.color`` names the pattern.
* A frame without ground truth is the row ``nan,nan,nan,nan``, which the toolkit reads as the
  state "unknown" (``vot.region.io.parse_region``: any NaN gives ``Special(0)``,
  ``Sequence.UNKNOWN``) and leaves out of its overlap analyses, as ``gflow eval`` scores only
  the frames with ground truth. Its supervised experiment cannot use such a sequence: it takes
  the overlap with an unknown region (0) for a failure and may re-initialise on a frame with no
  box, so :func:`stack_yaml` writes that experiment only for sequences labelled on every frame.
* Boxes are written with the digits they have (``204``, ``147.99``); VOT and gflow both count
  pixels from 0 with the box's corner at ``(x, y)``.
"""

from __future__ import annotations

import math
import shlex
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import cv2
import numpy as np

from pipeline.io.decoder_messages import decoder_messages
from pipeline.io.frame_readers import folder_frames

__all__ = ["ExportedSequence", "write_sequence", "write_list", "stack_yaml", "trackers_ini", "workspace_config",
           "box_text", "groundtruth_lines", "NAN_ROW"]

Box = tuple[float, float, float, float]

#: a frame without ground truth (the toolkit: state unknown, left out of its analyses)
NAN_ROW = "nan,nan,nan,nan"


@dataclass(frozen=True)
class ExportedSequence:
    """What :func:`write_sequence` wrote.

    first : the source frame index of VOT frame 1; length : frames written; labelled : of those,
    with a ground-truth box; size : (width, height); copied : frames copied byte for byte (else
    re-encoded as PNG); pattern : ``channels.color`` of the ``sequence`` file; damaged : a line for each frame
    decoded from damaged data (the decoder's words), written as it decodes, as ``gflow track`` tracks it."""

    name: str
    first: int
    length: int
    labelled: int
    size: tuple[int, int]
    copied: bool
    pattern: str
    damaged: tuple[str, ...] = ()

    @property
    def dense(self) -> bool:
        """Ground truth on every frame (what the toolkit's supervised experiment needs)."""
        return self.labelled == self.length


def box_text(box: Sequence[float]) -> str:
    """``x,y,w,h`` with the digits the numbers have (``204,150,17,50``, ``147.99,113.07,...``)."""
    return ",".join(np.format_float_positional(float(v), trim="-") for v in box)


def groundtruth_lines(groundtruth: Mapping[int, Box], first: int, length: int) -> list[str]:
    """One line per frame ``first .. first + length - 1``: the box, or :data:`NAN_ROW`."""
    return [box_text(groundtruth[f]) if f in groundtruth else NAN_ROW for f in range(first, first + length)]


def _decoded(path: Path) -> tuple[np.ndarray, list[str]]:
    """A frame decoded as the source stage decodes an image folder's (3-channel BGR), and what the decoder said of
    damaged data in it (empty for a clean decode)."""
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as e:
        raise OSError(f"cannot read {path}: {e.strerror or e}") from None
    with decoder_messages() as said:
        img = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    if img is None:
        raise ValueError(f"{path} is not a decodable image ({data.size} bytes); a VOT sequence needs every frame")
    return img, said


def write_sequence(folder: str | Path, name: str, frames: str | Path, groundtruth: Mapping[int, Box]) -> ExportedSequence:
    """Write one sequence in the VOT layout into ``folder`` (which must not exist yet).

    Parameters
    ----------
    folder : the sequence's folder, ``W/sequences/NAME``.
    name : the sequence's name.
    frames : an image folder numbered as ``gflow track`` numbers it (``000000.jpg`` ...).
    groundtruth : ``{frame: (x, y, w, h)}``, frame indices of that folder; the first one is VOT
        frame 1.

    Raises
    ------
    ValueError
        No ground truth, ground truth on a frame the folder does not have, a frame missing from
        the folder or not decodable, frames of different sizes.
    """
    if not groundtruth:
        raise ValueError(f"{name}: the ground truth has no box")
    if any(not all(math.isfinite(v) for v in b) or b[2] <= 0 or b[3] <= 0 for b in groundtruth.values()):
        bad = next(f for f, b in sorted(groundtruth.items()) if not all(math.isfinite(v) for v in b) or b[2] <= 0
                   or b[3] <= 0)
        raise ValueError(f"{name}: the ground-truth box of frame {bad} is not a box: {groundtruth[bad]}")
    files = dict(folder_frames(frames))
    first, last = min(groundtruth), max(files)
    if first not in files:
        raise ValueError(f"{name}: ground truth starts at frame {first}, which {frames} does not have "
                         f"(its frames are {min(files)}..{last})")
    beyond = [f for f in groundtruth if f > last]
    if beyond:
        raise ValueError(f"{name}: ground truth for frame {min(beyond)}, after the last frame of {frames} ({last})")
    order = list(range(first, last + 1))
    missing = [f for f in order if files.get(f) is None]
    if missing:
        raise ValueError(f"{name}: frame {missing[0]} is missing from {frames}; a VOT sequence needs every frame"
                         + (f" ({len(missing)} are missing)" if len(missing) > 1 else ""))
    paths = [files[f] for f in order]
    suffixes = {p.suffix.lower().replace(".jpeg", ".jpg") for p in paths if p is not None}
    copied = len(suffixes) == 1
    ext = suffixes.pop() if copied else ".png"
    out = Path(folder)
    color = out / "color"
    color.mkdir(parents=True)
    size: tuple[int, int] | None = None
    damaged: list[str] = []
    for k, src in enumerate(paths, start=1):
        assert src is not None
        img, said = _decoded(src)
        if said:
            damaged.append(f"{name}: frame {first + k - 1} ({src.name}) decoded from damaged data ({said[0]}); "
                           f"written as it is")
        shape = (img.shape[1], img.shape[0])
        if size is None:
            size = shape
        elif shape != size:
            raise ValueError(f"{name}: {src.name} is {shape[0]}x{shape[1]}, the frames before it {size[0]}x{size[1]}; "
                             "a VOT sequence has one frame size")
        dst = color / f"{k:08d}{ext}"
        if copied:
            shutil.copyfile(src, dst)
        elif not cv2.imwrite(str(dst), img):
            raise OSError(f"could not write {dst}")
    assert size is not None
    lines = groundtruth_lines(groundtruth, first, len(order))
    (out / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    pattern = f"color/%08d{ext}"
    meta = {"channels.color": pattern, "format": "default", "name": name, "width": size[0], "height": size[1],
            "length": len(order), "gflow.first_frame": first}
    (out / "sequence").write_text("".join(f"{k}={v}\n" for k, v in meta.items()))
    return ExportedSequence(name=name, first=first, length=len(order), labelled=sum(line != NAN_ROW for line in lines),
                            size=size, copied=copied, pattern=pattern, damaged=tuple(damaged))


def write_list(folder: str | Path, names: Sequence[str]) -> None:
    """``sequences/list.txt``: the sequences of the workspace, one a line."""
    (Path(folder) / "list.txt").write_text("".join(f"{n}\n" for n in names))


def stack_yaml(title: str, supervised: bool) -> str:
    """The experiment stack: ``baseline``, each sequence tracked once from its first frame (the
    toolkit's unsupervised experiment, as ``gflow benchmark`` runs it), with the overlap per
    sequence and its success curve at ``gflow eval``'s 21 thresholds 0, 0.05, ..., 1; and, with
    ``supervised``, ``reinit``, re-initialised 5 frames after each failure (overlap 0), with the
    toolkit's accuracy, robustness and failure counts. ``burnin: 1`` leaves the initialisation
    frame out of the overlaps (the toolkit would count it as 0 with ``burnin: 0``)."""
    import yaml

    baseline = {"type": "unsupervised", "repetitions": 1, "analyses": [
        {"type": "accuracy", "name": "overlap", "burnin": 1},
        {"type": "success_plot", "name": "success", "burnin": 1, "resolution": 21},
        {"type": "average_accuracy", "name": "average overlap", "burnin": 1},
        {"type": "average_success_plot", "name": "average success", "burnin": 1, "resolution": 21}]}
    experiments: dict = {"baseline": baseline}
    if supervised:
        experiments["reinit"] = {"type": "supervised", "repetitions": 1, "skip_initialize": 5, "analyses": [
            {"type": "supervised_ar", "name": "accuracy and robustness", "sensitivity": 30},
            {"type": "failures", "name": "failures"},
            {"type": "supervised_average_ar", "name": "average accuracy and robustness", "sensitivity": 30},
            {"type": "cumulative_failures", "name": "all failures"}]}
    return yaml.safe_dump({"title": title, "experiments": experiments}, sort_keys=False)


def trackers_ini(python: str, trackers: Mapping[str, Sequence[str]]) -> str:
    """``trackers.ini``: a TraX tracker ``gflow-NAME`` per entry, run as ``PYTHON -m gflow.trax ARGS``."""
    out = []
    for name, args in trackers.items():
        command = shlex.join([python, "-m", "gflow.trax", *args])
        out.append(f"[gflow-{name}]\nlabel = gflow {name}\nprotocol = trax\ncommand = {command}\n")
    return "\n".join(out)


def workspace_config() -> str:
    """``config.yaml``: the stack and the tracker registry beside it."""
    return "registry:\n- ./trackers.ini\nstack: ./stack.yaml\n"
