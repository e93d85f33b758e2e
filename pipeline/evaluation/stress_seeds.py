"""``gflow benchmark --stress --seeds 1,2,3``: each seed's stress summary side by side.

The stress benchmark is run once per seed (each seed derives its own cases: the occluders' patches
and places, the rolls' and the blur's draws, and seeds the trackers); after each seed's tables, one
table per tracker puts the figures the stress benchmark is judged by next to each other, a column a
seed: the cases got back (every case, full occlusions of up to 60 frames, rolls of up to 35 degrees,
fast motion), the mean success, and the reported states (hidden frames reported ``occluded`` or
``lost``, undisturbed frames reported ``tracked``, frames with the box off the target reported
``tracked``), each as a count of its total.
"""

from __future__ import annotations

from pipeline.evaluation.benchmark_tables import table, title

__all__ = ["format_stress_seeds"]

#: (the row's label, the summary's key, the group under "back")
ROWS = (("got back, every case", "back", "every case"),
        ("got back, full occlusions <= 60 frames", "back", "full occlusion <= 60 frames"),
        ("got back, rolls <= 35 degrees", "back", "roll <= 35 degrees"),
        ("got back, fast motion", "back", "fast motion"),
        ("mean success", "mean_success", None),
        ("hidden frames reported occluded / lost", "hidden_reported_occluded_or_lost", None),
        ("undisturbed frames reported tracked", "undisturbed_reported_tracked", None),
        ("off-target frames reported tracked (lower is better)", "off_target_reported_tracked", None))


def _cell(summary: dict | None, key: str, group: str | None) -> str:
    """One figure of one seed's summary of one tracker: "a / b (rate)" for a count, the value for a mean."""
    if summary is None:
        return "-"
    v = summary.get(key)
    if group is not None and isinstance(v, dict):
        v = v.get(group)
    if v is None:
        return "-"
    if isinstance(v, list):
        a, b = v
        return f"{a} / {b}" + (f" ({a / b:.3f})" if group is None and b else "")
    return f"{v:.3f}"


def format_stress_seeds(summaries: list[dict], seeds: list[int], markdown: bool = False) -> str:
    """One table per tracker of its summary (``summaries[i]``: {tracker: the stress JSON's summary} of seed
    ``seeds[i]``), a column a seed."""
    names = list(dict.fromkeys(n for s in summaries for n in s))
    out: list[str] = []
    for name in names:
        head = ["", *(f"seed {s}" for s in seeds)]
        cells = [[label, *(_cell(s.get(name), key, group) for s in summaries)] for label, key, group in ROWS]
        out += [title(name, f"the stress cases with each seed: {', '.join(map(str, seeds))}", markdown), "",
                table(head, cells, markdown, left={0}), ""]
    return "\n".join(out).rstrip()
