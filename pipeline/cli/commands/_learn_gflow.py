"""``gflow learn gflow``: a morphable face model (eq. 1) from 3-D landmark tracks.

The mathematics is :mod:`gflow_core.gflow.morphable_learn` (Procrustes, frontal frame, vertex
choice, PCA morph bases); this module reads the landmark files (:mod:`pipeline.io.landmarks`)
and boxes, and writes the model file (:mod:`pipeline.io.modelfile`, kind ``morphable``, with
``landmarks``, ``reference_box`` and ``morph_std``) with how it was made as metadata.
"""

from __future__ import annotations

import argparse
import sys
import textwrap
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.cli.commands.common import CliError, whole_number

if TYPE_CHECKING:  # numpy is imported where used: the command's options and --help need none
    import numpy as np

#: default number of vertices kept (farthest-point sampling of the 468 landmarks)
DEFAULT_VERTICES = 160


def _boxes_for(source: Path, frames: int, box_file: str | None) -> np.ndarray:
    """(frames, 4) boxes of a landmark file's frames (NaN rows where the box file has none)."""
    import numpy as np

    from pipeline.evaluation.scored_boxes import read_scored_boxes

    path = Path(box_file) if box_file else source.parent / "groundtruth.csv"
    if not path.is_file():
        raise CliError(f"--boxes: {path} not found" + ("" if box_file else f" (the ground truth beside {source})"))
    b = read_scored_boxes(path).boxes  # rows of no box (the target absent) left out; a negative size refused
    out = np.full((frames, 4), np.nan)
    for f, box in b.items():
        if 0 <= f < frames:
            out[f] = box
    return out


def cmd_learn_gflow(args) -> int:
    from pipeline.cli.commands.common import check_model_out, frame_range, range_past_note, say_notes, start_work

    # the options first: a mistyped one fails before the learning's modules (SciPy) are imported
    check_model_out(args.out)
    if args.k < 1:
        raise CliError(f"-k must be a positive number of morph bases, got {args.k}")
    n_vertices = None if args.vertices in ("all", "0") else _positive_int(args.vertices)
    start, stop = frame_range(args.frames)
    if args.boxes is not None and args.boxes and len(args.boxes) != len(args.sources):
        raise CliError(f"--boxes: give one box file per source ({len(args.sources)}), or none to use each source's "
                       f"groundtruth.csv")

    import numpy as np

    from gflow_core.gflow.morphable_learn import learn_morphable

    from pipeline.io.landmarks import read_landmarks, resolve_landmarks
    from pipeline.io.modelfile import save_model
    from pipeline.cli.commands.common import refuse_same_source

    refuse_same_source([resolve_landmarks(src) for src in args.sources], list(args.sources), "landmark source")
    tracks, boxes, names, used, past = [], [], [], [], []
    for i, src in enumerate(args.sources):
        path = resolve_landmarks(src)
        lm = read_landmarks(path, key=args.key, dims=(3,))
        _refuse_other_layout(path, lm.shape[1])
        sel = slice(start, stop)
        frames = np.arange(lm.shape[0])[sel]
        if frames.size == 0:
            raise CliError(f"{path} has {lm.shape[0]} frames: none in --frames {args.frames}")
        tracks.append(lm[sel])
        if args.boxes is not None:
            boxes.append(_boxes_for(path, lm.shape[0], args.boxes[i] if args.boxes else None)[sel])
        names.append(str(path))  # as given (the shipped model says ../shared/data/..., not this machine's path)
        used.append(f"{frames[0]}:{frames[-1] + 1}")
        past.append(range_past_note(f"--frames {args.frames}", (start, stop), str(path), (0, lm.shape[0] - 1),
                                    (int(frames[0]), int(frames[-1])), "learning from"))
        if not args.quiet:
            ok = int(np.isfinite(lm[sel]).all(axis=(1, 2)).sum())
            print(f"read {path}: {lm.shape[1]} landmarks, {frames.size} frames ({ok} with a face)", file=sys.stderr)
    _check_enough(tracks, boxes, args.k, args.frames)
    say_notes(*past)
    start_work()  # the options and training frames checked: a value the learning refuses is its failure (exit 1)
    try:
        face = learn_morphable(tracks, k=args.k, n_vertices=n_vertices, boxes=boxes if boxes else None)
    except ValueError as e:
        raise ValueError(f"cannot learn a face model: {e}") from None
    m = face.model
    meta = {"source": ";".join(names), "frames": ";".join(used), "training_frames": face.frames, "k": m.n_bases,
            "vertices": m.n_vertices, "boxes": "yes" if boxes else "no",
            "explained": face.explained, "residual_rms": face.residual_rms,
            "command": "gflow learn gflow " + " ".join(sys.argv[3:]) if sys.argv[1:3] == ["learn", "gflow"] else ""}
    out = save_model(args.out, m, meta=meta, new=True)
    expl = ", ".join(f"{100 * v:.0f}%" for v in face.explained) or "none (k = 1)"
    print(f"learned a morphable face model: k={m.n_bases} bases (the mean shape and {m.n_bases - 1} morphs), "
          f"n={m.n_vertices} vertices, from {face.frames} frames; deformation variance per morph: {expl}; "
          f"residual {face.residual_rms:.4f} face heights RMS; written to {out}")
    return 0


def _refuse_other_layout(path, n: int) -> None:
    """Landmarks of another layout than MediaPipe Face Mesh's (fewer than its eye and mouth corners need): the
    learning failed after reading every file, exit 1, with "frontal landmarks (33, 263, 61, 291) must lie in
    [0, n)"; a mistake in the input, said before any learning and naming the file."""
    from gflow_core.gflow.morphable_learn import EVAL_LANDMARKS, FRONTAL_MEDIAPIPE

    corners = sorted(set(FRONTAL_MEDIAPIPE) | set(EVAL_LANDMARKS))
    if n <= corners[-1]:
        raise CliError(f"{path}: {n} landmarks a frame; gflow learn gflow reads MediaPipe Face Mesh's layout (468, the "
                       f"eye and mouth corners at {', '.join(map(str, corners))})")


def _check_enough(tracks: list[np.ndarray], boxes: list[np.ndarray], k: int, frames: str | None) -> None:
    """The training frames enough for ``-k`` (and, with --boxes, one with a box): a mistake in the command
    (exit 2), said before the learning begins, rather than the learning's failure."""
    import numpy as np

    where = f" in --frames {frames}" if frames else ""
    good = [np.isfinite(t).all(axis=(1, 2)) for t in tracks]
    n = int(sum(g.sum() for g in good))
    if n == 0:
        raise CliError(f"cannot learn a face model: no frame{where} has all its landmarks (every frame has a NaN)")
    if n < k:
        raise CliError(f"cannot learn a face model: -k {k} morph bases need at least {k} frames with landmarks, "
                       f"got {n}{where}; use a smaller -k or more frames")
    if boxes and not any((np.isfinite(b[g]).all(axis=1) & (b[g][:, 2] > 0) & (b[g][:, 3] > 0)).any()
                         for b, g in zip(boxes, good)):
        raise CliError(f"cannot learn a face model: no frame{where} has both landmarks and a box (--boxes)")


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise CliError(f"--vertices expects a number or 'all', got {text!r}") from None
    if v < 3:
        raise CliError(f"--vertices must be at least 3 (or 'all'), got {v}")
    return v


def add_parser(models) -> None:
    """``gflow learn gflow`` under the ``learn`` command's model subparsers."""
    q = models.add_parser(
        "gflow", help="a morphable face model (G-flow, eq. 1) from 3-D landmark tracks",
        description=textwrap.fill(
            "Learn a morphable model x_i = g r h_i c + l (Marks et al. 2004, eq. 1) from 3-D face landmarks tracked "
            "in one or more videos: each frame's rigid pose and scale are removed (generalised orthogonal "
            "Procrustes), the mean is turned to face the camera (eye corners 33 -> 263 along +x, mouth below) and "
            "scaled to 1 unit high, the vertices are chosen (farthest-point sampling; the eye and mouth corners "
            "33, 133, 362, 263, 61, 291 always kept), and the k morph bases are the mean shape and the k - 1 "
            "leading principal deformations. Each vertex keeps the index of the landmark it came from. Any "
            "landmark source in MediaPipe Face Mesh's layout (468 points, indices as MediaPipe's; x, y in pixels, "
            "z in the same units, NaN for frames without a face) works, e.g. ../shared/data/david_indoor/"
            "landmarks.npz. Track with `gflow track SOURCE --tracker gflow --model MODEL.npz --init X,Y,W,H`.", 90),
        epilog="examples:\n"
               "  gflow learn gflow ../shared/data/david_indoor --boxes --out face.npz\n"
               "  gflow learn gflow ../shared/data/david_indoor --boxes --frames 0:335 -k 5 --vertices 160 "
               "--out face-first-half.npz\n"
               "  gflow learn gflow a/landmarks.npz b/landmarks.npz --out faces.npz   # two videos, one model",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    q.add_argument("sources", nargs="+", metavar="LANDMARKS",
                   help="landmark file (.npz, (frames, 468, 3) under --key) or a dataset folder holding landmarks.npz")
    q.add_argument("--out", required=True, metavar="MODEL.npz", help="model file to write")
    q.add_argument("-k", type=whole_number, default=5,
                   help="morph bases, the first being the mean shape (default 5, as in the paper)")
    q.add_argument("--vertices", default=str(DEFAULT_VERTICES), metavar="N",
                   help=f"vertices kept, or 'all' (default {DEFAULT_VERTICES}: evenly spread over the face)")
    q.add_argument("--boxes", metavar="GT.csv", nargs="*",
                   help="boxes (frame,x,y,w,h) of the same frames, one file per source, or no file: the "
                        "groundtruth.csv beside each landmark file; where they sit on the face is the model's "
                        "reference box, which `gflow track --init` is read against (default: the face's outline)")
    q.add_argument("--frames", metavar="A:B", help="learn from frames A <= index < B (default: all)")
    q.add_argument("--key", default="landmarks", help="name of the landmark array in the files (default landmarks)")
    q.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    q.set_defaults(func=cmd_learn_gflow)
