"""A comma-separated list of names, as the commands read one (``--trackers dcf,m2``, ``--sequences``,
``--cases``, ``--opencv``): a module that imports nothing, so that any layer above can read one alike."""

from __future__ import annotations

__all__ = ["comma_names"]


def comma_names(text: str, option: str) -> list[str]:
    """The names of ``text`` (``"a, b"`` -> ``["a", "b"]``), in the order given. ValueError (one line naming
    ``option`` and the value) for a name given twice, which was run or kept once without a word, or an empty
    name between commas (``dcf,,m2``, ``dcf,$T`` with T unset), which was dropped without a word. Text that names
    nothing (``''``, ``,``) gives ``[]``: the caller says what it needs."""
    parts = [n.strip() for n in text.split(",")]
    if not any(parts):
        return []
    if not all(parts):
        raise ValueError(f"{option} {text!r}: an empty name between commas; give each name once, e.g. a,b")
    twice = next((n for i, n in enumerate(parts) if n in parts[:i]), None)
    if twice is not None:
        raise ValueError(f"{option} {text!r}: {twice} is named twice; give each name once")
    return parts
