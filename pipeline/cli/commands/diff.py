"""``gflow diff A.mcap B.mcap``: which messages differ, where they first diverge, by how much."""

from __future__ import annotations

import json
import sys


ORDER = 54


def cmd_diff(args) -> int:
    import numpy as np

    from pipeline.io.mcap_io import recorded_topics
    from pipeline.recording.diff import diff_recordings
    from pipeline.recording.topics import stream_prefix
    from pipeline.cli.commands.common import CliError, chosen_topics

    topics = None
    if args.topics:  # as typed (estimate, gflow/demo/estimate, *): one that names nothing is an error
        topics = chosen_topics(args.topics, set(recorded_topics(args.a)) | set(recorded_topics(args.b)),
                               where=f"{args.a} or {args.b}")
    from pipeline.cli.commands.common import warn_if_torn

    for path in (args.a, args.b):
        warn_if_torn(path)
    res = diff_recordings(args.a, args.b, topics)
    from pipeline.io.mcap_io import damage_cause, torn_cause

    if not any(d.same or d.differ or d.only_a or d.only_b for d in res.values()):
        # nothing compared is no evidence that they are the same
        files = list(dict.fromkeys((args.a, args.b)))
        why = "; ".join(damage_cause(p) or (f"{p}: {torn_cause(p)}" if torn_cause(p) else "") for p in files)
        which = f"neither {args.a} nor {args.b} holds a" if len(files) == 2 else f"{args.a} holds no"
        why = why.strip("; ")
        raise CliError(f"nothing to compare: {which} message that can be read" + (f" ({why})" if why else ""))
    # a damaged file is compared only up to the damage: its verdict is not the recording's
    damaged = "; ".join(c for c in dict.fromkeys(damage_cause(p) for p in (args.a, args.b)) if c)
    across = next(((d.topic_a, d.topic_b) for d in res.values() if d.topic_a and d.topic_b and d.topic_a != d.topic_b), None)
    if args.json:
        print(json.dumps({t: {"topic_a": d.topic_a, "topic_b": d.topic_b, "types": sorted(d.types), "same": d.same,
                              "differ": d.differ, "only_a": d.only_a, "only_b": d.only_b, "first_divergence": d.first_divergence,
                              "fields": {k: (None if np.isnan(v) else v) for k, v in d.fields.items()},
                              "estimates": [e.__dict__ for e in d.estimates if e.centre_px or e.pose]}
                          for t, d in res.items()}, indent=1))
        if damaged:
            print(f"gflow diff: {damaged}", file=sys.stderr)
            _told(args)
        return 0 if all(d.identical for d in res.values()) and not damaged else 1
    print(f"A = {args.a}\nB = {args.b}")
    if across is not None:
        print(f"paired across run ids: A's {stream_prefix([across[0]])} with B's {stream_prefix([across[1]])} "
              "(the same graph's topics, compared by their name without the run id)")
    print(f"{'topic':40s} {'type':22s} {'same':>6s} {'differ':>6s} {'only A':>6s} {'only B':>6s}  first divergence")
    for t, d in res.items():
        fd = "-" if d.first_divergence is None else f"frame {d.first_divergence}"
        print(f"{t:40s} {'+'.join(sorted(d.types)):22s} {d.same:6d} {d.differ:6d} {d.only_a:6d} {d.only_b:6d}  {fd}")
        if d.fields:
            parts = [f"{k} (max |diff| {v:.4g})" if not np.isnan(v) else k for k, v in sorted(d.fields.items())]
            print(f"    fields that differ: {', '.join(parts)}")
    for t, d in res.items():
        est = [e for e in d.estimates if e.centre_px > 0 or e.pose > 0]
        if not d.estimates:
            continue
        c = np.array([e.centre_px for e in d.estimates])
        print(f"\n{t}: box centre difference over {len(c)} frames: mean {c.mean():.2f} px, max {c.max():.2f} px "
              f"(frame {d.estimates[int(c.argmax())].seq}); min overlap {min(e.overlap for e in d.estimates):.3f}; "
              f"first frame with a different estimate: {est[0].seq if est else '-'}")
        if args.frames:
            print(f"  {'frame':>6s} {'centre px':>10s} {'overlap':>8s} {'pose max|diff|':>15s}")
            for e in d.estimates:
                print(f"  {e.seq:6d} {e.centre_px:10.3f} {e.overlap:8.3f} {e.pose:15.6g}")
    same = all(d.identical for d in res.values())
    if damaged:  # exit 1 either way: what could not be read was not compared
        _told(args)
        print(f"\n{'identical up to the damage' if same else 'the recordings differ'}; nothing after the damage was "
              f"compared: {damaged}")
        return 1
    print("\nidentical" if same else "\nthe recordings differ")
    return 0 if same else 1


def _told(args) -> None:
    """The damage of either recording is said by diff's own line: not warned again when the command ends."""
    from pipeline.io.mcap_io import damage_cause, damage_told

    for p in (args.a, args.b):
        damage_told(damage_cause(p))


def register(sub) -> None:
    p = sub.add_parser("diff", help="compare two recordings topic by topic",
                       description="Pairs messages by topic and frame (two runs of one graph, whose topics differ "
                                   "only by their run ids, are paired by the topic name without the run id); prints, "
                                   "per topic, how many differ, in which fields and by how much, and where they first diverge; for estimates the box and "
                                   "pose difference per frame. Exit status 1 if they differ.")
    p.add_argument("a", help="first recording")
    p.add_argument("b", help="second recording")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="only these topics: the name in the stream (estimate), the full name with or without "
                        "the run id (gflow/demo/estimate), or a shell pattern (gflow/*/estimate)")
    p.add_argument("--frames", action="store_true", help="print the estimate difference of every frame")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_diff)
