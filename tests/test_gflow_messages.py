"""G-flow's messages packed and read by gflow_msgs.gflow: what travels comes back as it was, and a
message that is not the receiver's (another digest or shard, an empty shard, a bad time step, other
experts, a wrong array) is refused in one line saying which."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from gflow_msgs.base import Header, MessageError
from gflow_msgs.gflow import proposals_of, read_proposals, read_shards, read_states, states_of
from gflow_msgs.messages import decode, encode

H = Header(stream="s", seq=3, stamp_ns=0)
E, P, N, S = 4, 7, 5, 3


def _experts(rng: np.random.Generator, anchor: bool) -> SimpleNamespace:
    return SimpleNamespace(poses=rng.normal(size=(E, P)), tex_mean=rng.normal(size=(E, N)),
                           tex_var=rng.uniform(1, 2, (E, N)), log_credibility=rng.normal(size=E),
                           tex_anchor=rng.normal(size=N) if anchor else None)


def _proposals(rng: np.random.Generator, idx: np.ndarray) -> SimpleNamespace:
    n = idx.size
    return SimpleNamespace(expert_indices=idx, u_hat=rng.normal(size=(n, P)), sigma_hat=rng.normal(size=(n, P, P)),
                           samples=rng.normal(size=(n, S, P)), log_weights=rng.normal(size=(n, S)),
                           log_evidence=rng.normal(size=n), gn_objective=rng.normal(size=n),
                           reset=np.array([False, True])[: n], dt=2.0)


@pytest.mark.parametrize("anchor", [False, True])
def test_expert_states_come_back_as_they_were_sent(anchor) -> None:
    rng = np.random.default_rng(0)
    ex, parents = _experts(rng, anchor), np.array([0, 0, 2, 3])
    msg = decode(encode(states_of(H, ex, parents, (24, 32), "abc", first=True)))
    out = read_states(msg, {"E": E, "P": P, "n": N}, "abc")
    for k in ("poses", "tex_mean", "tex_var", "log_credibility", "tex_anchor"):
        got, want = out[k], getattr(ex, k)
        assert (got is None and want is None) or np.array_equal(got, want)
    assert np.array_equal(out["parents"], parents) and msg.first and msg.image_shape == (24, 32)
    with pytest.raises(MessageError, match="another G-flow configuration.*digest abc, this stage has xyz"):
        read_states(msg, {"E": E, "P": P, "n": N}, "xyz")
    with pytest.raises(MessageError, match=r"poses must be float64 \(5, 7\)"):
        read_states(msg, {"E": 5, "P": P, "n": N}, None)


def test_a_shards_proposals_come_back_and_what_is_not_the_filters_is_refused() -> None:
    rng = np.random.default_rng(1)
    idx = np.array([2, 3])
    msg = decode(encode(proposals_of(H, _proposals(rng, idx), 1, 2, "abc")))
    dims = {"P": P, "s": S}
    out = read_proposals(msg, "abc", 1, 2, idx, dims, 25.0)
    assert out["dt"] == 2.0 and out["reset"].tolist() == [False, True] and out["samples"].shape == (2, S, P)
    refusals = [(("xyz", 1, 2, idx, 25.0), "another G-flow configuration"),
                (("abc", 0, 2, idx, 25.0), "expected shard 0 of 2, got shard 1 of 2"),
                (("abc", 1, 2, np.array([1, 2]), 25.0), r"expert indices \[2, 3\] are not this shard's \[1, 2\]"),
                (("abc", 1, 2, idx, 1.5), r"dt must be in \[1, 1.5\] frame periods, got 2.0")]
    for (digest, shard, shards, expected, max_dt), says in refusals:
        with pytest.raises(MessageError, match=says):
            read_proposals(msg, digest, shard, shards, expected, dims, max_dt)
    empty = decode(encode(proposals_of(H, None, 1, 2, "abc")))
    with pytest.raises(MessageError, match="had no usable frame or expert state"):
        read_proposals(empty, "abc", 1, 2, idx, dims, 25.0)
    # every shard of a frame: each read as its own, or the first that did not come or does not read named
    first = decode(encode(proposals_of(H, _proposals(rng, np.array([0, 1])), 0, 2, "abc")))
    parts, problem = read_shards([first, msg], "abc", [np.array([0, 1]), idx], dims, 25.0)
    assert problem is None and [p["expert_indices"].tolist() for p in parts] == [[0, 1], [2, 3]]
    assert read_shards([first, None], "abc", [np.array([0, 1]), idx], dims, 25.0) == (
        None, ("missing_proposals", "no proposals from shard 1 of 2"))
    parts, problem = read_shards([msg, first], "abc", [np.array([0, 1]), idx], dims, 25.0)
    assert parts is None and problem is not None and problem[0] == "bad_proposals"
    assert problem[1].startswith("proposals of shard 0: expected shard 0 of 2, got shard 1 of 2")
