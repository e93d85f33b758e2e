"""`gflow step` drives a stage through a recording from commands on standard input."""

from __future__ import annotations

import subprocess

from pipeline.runtime.build import apply_defaults
from pipeline.runtime.graph import load_graph
from pipeline.runtime.inline import run_inline


def test_step_next_jump_and_state(tmp_path, gflow_cmd):
    rec = tmp_path / "demo.mcap"
    plan = apply_defaults(load_graph("demo", overrides={"source": {"frames": 60}, "filter": {"particles": 100}}))
    md = {"gflow.graph": {"yaml": plan.source_text}, "gflow.config": plan.config_metadata()}
    run_inline(plan, recording=str(rec), metadata=md)
    out = subprocess.run([*gflow_cmd, "step", str(rec), "--stage", "filter"], input="n\nn\nj 40\ns\nbogus\nn\nq\n",
                         capture_output=True, text=True, timeout=120)
    # a command not known, piped in, is a mistake in the script: it stops there (exit 2, one line, saying which line)
    # rather than stepping on past what the script meant
    assert out.returncode == 2, (out.stdout, out.stderr)
    assert out.stderr.count("\n") == 1 and "Traceback" not in out.stderr, out.stderr
    assert "standard input line 5: unknown command 'bogus'" in out.stderr, out.stderr
    text = out.stdout
    assert "snapshots at [0, 25, 50]" in text
    assert "--- frame 0 " in text and "--- frame 1 " in text and "--- frame 40 " in text
    assert "jumped from the snapshot at frame 25" in text
    assert "proposals  (missing)" in text  # the first frame has no proposals: the filter initialises
    assert "Estimate seq=40" in text and '"ess"' in text
    assert '"weights_N*W"' in text and '"best_particle"' in text  # weights histogram and best particle
    assert "--- frame 41 " not in text  # the n after the mistake was not carried out
