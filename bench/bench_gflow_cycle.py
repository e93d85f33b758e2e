"""G-flow's critical path as processes: the CPU of the proposal stage's and the filter stage's step
per frame on real video (../shared/data/david_indoor, the default settings, 20 experts).

One command: ``python bench/bench_gflow_cycle.py [--frames 150] [--repeat 2] [--compare DIR]``

As processes, G-flow is a cycle: the proposals of frame t need the experts after frame t - 1, the
filter needs the proposals of frame t, so each frame waits for one proposal step and one filter step,
one after the other, plus two message hops; the source, the preprocessing, the recorder and what each
stage prepares from the frame alone (``Stage.prepare``, run on a stage process's second thread as soon
as the frame arrives) run beside the cycle on the other core. This benchmark drives both stages in
one process, as the stage processes do: messages encoded and decoded as on the wire, each stage's
``prepare`` (where it has one) run before its step and timed apart. It reports the CPU time
(``time.process_time``, which the other jobs of a shared machine do not inflate as they do the wall
clock) of each stage's step per frame, of their prepare, and the cycle's sum (the step times).

``--compare DIR`` runs the same benchmark on the code of another checkout (a worktree of an older
commit, say: ``git worktree add /tmp/old COMMIT``) alternately with this one, ``--repeat`` times
each, so both see the same load; the boxes of the two are printed too (equal when a change keeps
the results).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT.parent / "shared" / "data" / "david_indoor"
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import checkout  # noqa: E402


def measure(frames: int) -> dict:
    """Run the cycle on the first ``frames`` frames with the code importable here; CPU ms per frame."""
    import cv2
    import msgspec
    import numpy as np

    from gflow_core import colour
    from gflow_core.features import to_grey
    from pipeline.io.modelfile import load_model, model_path
    from stages.base import StageContext
    from stages.gflow_filter import GFlowFilterParams, GFlowFilterStage
    from stages.gflow_proposal import GFlowProposalParams, GFlowProposalStage
    from gflow_msgs.messages import ColourFeatures, Header, NDArray, decode, encode

    files = sorted(p for p in (DATA / "frames").iterdir() if p.suffix == ".jpg")[:frames]
    first = (DATA / "groundtruth.csv").read_text().splitlines()[1].split(",")
    params = {"init": [float(v) for v in first[1:5]], "seed": 1, "model": "face"}
    res = {"model": load_model(model_path("face"))}
    prop = GFlowProposalStage(msgspec.convert(params, GFlowProposalParams), StageContext("proposal", "cam0", resources=res))
    filt = GFlowFilterStage(msgspec.convert(params, GFlowFilterParams), StageContext("filter", "cam0", resources=res))
    z = np.zeros((1, 1), np.uint8)

    def wire(m):
        return None if m is None else decode(encode(m))

    def ahead(stage, port, msg) -> float:
        """The stage's prepare of ``msg``, as its process's second thread runs it (CPU seconds)."""
        if not getattr(stage, "prepare_ports", None):
            return 0.0
        c = time.process_time()
        r = stage.prepare(port, msg)
        stage.ahead[(port, msg.header.seq)] = lambda: r
        return time.process_time() - c

    cpu = {"proposal": 0.0, "filter": 0.0, "proposal prepare": 0.0, "filter prepare": 0.0}
    state = est = None
    for t, f in enumerate(files):
        img = cv2.imread(str(f))
        feat = ColourFeatures(Header("cam0", t, t * 40_000_000), NDArray.of(to_grey(img)), NDArray.of(z),
                              NDArray.of(z.astype(np.float32)), "truncated", 100.0, bins=NDArray.of(colour.bins(img)))
        fp, ff = wire(feat), wire(feat)
        pp, pf = ahead(prop, "features", fp), ahead(filt, "features", ff)
        c0 = time.process_time()
        props = dict(prop.step(t, {"features": fp, "state": wire(state)})).get("proposals")
        c1 = time.process_time()
        out = dict(filt.step(t, {"features": ff, "proposals0": wire(props)}))
        c2 = time.process_time()
        state, est = out["state"], out["estimate"]
        if t > 0:  # the first frame places the model: not a tracking step
            cpu["proposal"] += c1 - c0
            cpu["filter"] += c2 - c1
            cpu["proposal prepare"] += pp
            cpu["filter prepare"] += pf
    n = max(len(files) - 1, 1)
    out_ms = {k: 1e3 * v / n for k, v in cpu.items()}
    out_ms["cycle"] = out_ms["proposal"] + out_ms["filter"]
    return {"ms": out_ms, "box": [round(v, 6) for v in est.box], "frames": len(files)}


def run_in(code: Path, frames: int) -> dict:
    """:func:`measure` in a fresh interpreter importing the code of ``code``."""
    env = dict(os.environ, PYTHONPATH=str(code), OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
               MKL_NUM_THREADS="1")
    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--frames", str(frames), "--child"],
                         cwd=code, env=env, capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(f"the benchmark failed in {code}:\n{out.stderr}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=150, help="frames of david_indoor (default 150)")
    ap.add_argument("--repeat", type=int, default=2, help="runs of each checkout, alternated (default 2)")
    ap.add_argument("--compare", metavar="DIR", help="another checkout to run alternately with this one")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    codes = [("this", ROOT)] + ([("compare", checkout(ap, args.compare))] if args.compare else [])
    if not DATA.is_dir():
        raise SystemExit(f"{DATA} not found: this benchmark needs ../shared/data/david_indoor")
    if args.child:
        import cv2

        cv2.setNumThreads(1)  # as in a stage process (pipeline/runtime/stage_host.py)
        print(json.dumps(measure(args.frames)))
        return
    results: dict[str, list[dict]] = {name: [] for name, _ in codes}
    for _ in range(args.repeat):
        for name, code in codes:
            results[name].append(run_in(code, args.frames))
    print(f"G-flow cycle on david_indoor, {args.frames} frames, 20 experts; CPU ms per frame (process_time), "
          f"best of {args.repeat}; load average {os.getloadavg()[0]:.1f}")
    keys = ["proposal", "filter", "cycle", "proposal prepare", "filter prepare"]
    print(f"{'code':<10}" + "".join(f"{k:>18}" for k in keys) + "  last box")
    for name, code in codes:
        best = {k: min(r["ms"][k] for r in results[name]) for k in keys}
        print(f"{name:<10}" + "".join(f"{best[k]:>18.1f}" for k in keys) + f"  {results[name][-1]['box']}")
    if args.compare:
        print(f"compare: {codes[1][1]}")


if __name__ == "__main__":
    main()
