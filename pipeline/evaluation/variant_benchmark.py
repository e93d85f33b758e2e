"""``gflow benchmark DATA --variant NAME``: the benchmark on a variant of every sequence.

For each sequence folder a derived folder is written: ``frames/`` (each frame the variant keeps
of the run, through the variant's transform, :data:`gflow_core.evaluation.variants.VARIANTS`, as a
lossless PNG named for its derived index) and ``groundtruth.csv`` (the original, byte for byte,
where the variant keeps every frame at its size; otherwise the kept frames' boxes, renumbered and
scaled as the frames were). The published results (``results/*.csv``) are left out: they were made
on the original frames, not on these. The derived folders then run through the plain benchmark
(:mod:`pipeline.evaluation.sequence_benchmark`), so the trackers, OpenCV's trackers and the box
that never moves all see the same derived frames and are scored the same way. The folders live
under a temporary folder the benchmark removes.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2

from gflow_core.evaluation.variants import Variant

from pipeline.io.frame_readers import folder_frames
from pipeline.evaluation.sequence_benchmark import Sequence
from pipeline.recording.results import read_boxes, write_boxes

__all__ = ["derive_variant"]


def derive_variant(seq: Sequence, variant: Variant, root: Path, start: int, stop: int | None) -> Sequence:
    """Write ``seq``'s frames ``start <= i < stop`` that ``variant`` keeps, through its transform, to
    ``root/SEQUENCE`` with their ground truth; the derived sequence (same name, no published results;
    its frames numbered from ``start`` and all below ``stop``). ValueError / OSError (one line) for a
    frame that cannot be read or written."""
    folder = root / seq.name
    frames = folder / "frames"
    frames.mkdir(parents=True, exist_ok=False)
    for i, src in folder_frames(seq.path / "frames"):
        j = variant.index(i, start)
        if src is None or j is None or (stop is not None and i >= stop):
            continue  # a missing frame stays missing: the source reports it as on the original
        img = cv2.imread(str(src), cv2.IMREAD_COLOR)
        if img is None:
            raise ValueError(f"{src}: not a decodable image")
        dst = frames / f"{j:06d}.png"
        if not cv2.imwrite(str(dst), variant.transform(img, i)):
            raise OSError(f"could not write {dst}")
    if variant.keeps_truth:
        shutil.copyfile(seq.path / "groundtruth.csv", folder / "groundtruth.csv")
        truth = seq.groundtruth
    else:
        kept = {f: b for f, b in seq.groundtruth.items() if stop is None or f < stop}
        write_boxes(folder / "groundtruth.csv", variant.truth(kept, start))
        truth = read_boxes(folder / "groundtruth.csv")  # as written (two decimals), so the file and the scores agree
    return Sequence(name=seq.name, path=folder, groundtruth=truth, results=())
