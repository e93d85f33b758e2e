"""numpy, OpenCV and OpenBLAS held to x86-64-v3 in every gflow process (pipeline/runtime/instruction_sets.py):
what is set on which CPU, that the libraries know every name set (a misspelt one is ignored by numpy and only
warned of by OpenCV, and would hold nothing), and that the commands and the stage processes run held."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.runtime.instruction_sets import _NUMPY_OFF, _OPENCV_AVX512, HELD, cpu_flags, hold

ROOT = Path(__file__).resolve().parent.parent
AVX2 = frozenset({"sse4_2", "avx", "avx2", "fma"})
SKX = AVX2 | {"avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl"}


def test_an_avx512_cpu_gets_every_switch_and_opencv_only_the_features_it_has():
    env: dict[str, str] = {}
    done = hold(env, flags=SKX, machine="x86_64")
    assert done == env and set(env) == set(HELD)
    assert env["OPENCV_IPP"] == "avx2" and env["OPENBLAS_CORETYPE"] == "Haswell"
    assert env["NPY_DISABLE_CPU_FEATURES"] == _NUMPY_OFF
    assert env["OPENCV_CPU_DISABLE"].split(",") == ["AVX512F", "AVX512CD", "AVX512BW", "AVX512DQ", "AVX512VL",
                                                   "AVX512-COMMON", "AVX512-SKX"]


def test_an_avx2_cpu_gets_no_opencv_list_so_opencv_warns_of_nothing():
    env: dict[str, str] = {}
    hold(env, flags=AVX2, machine="x86_64")
    assert "OPENCV_CPU_DISABLE" not in env and env["OPENBLAS_CORETYPE"] == "Haswell"


@pytest.mark.parametrize("env, flags, machine", [
    ({"GFLOW_SIMD": "native"}, SKX, "x86_64"),       # told not to
    ({}, frozenset({"sse4_2", "avx"}), "x86_64"),    # no AVX2: no common level to hold to
    ({}, SKX, "aarch64"),                            # not x86-64
])
def test_nothing_is_held_where_it_should_not_be(env, flags, machine):
    before = dict(env)
    assert hold(env, flags=flags, machine=machine) == {} and env == before


def test_what_the_user_set_is_left_as_it_is():
    env = {"OPENBLAS_CORETYPE": "SkylakeX"}
    done = hold(env, flags=SKX, machine="x86_64")
    assert env["OPENBLAS_CORETYPE"] == "SkylakeX" and "OPENBLAS_CORETYPE" not in done


def test_numpy_knows_every_name_held():
    """numpy ignores a name it does not know: each must be one of its dispatch targets."""
    import numpy as np

    known = set(np._core._multiarray_umath.__cpu_dispatch__) | set(np._core._multiarray_umath.__cpu_features__)
    assert set(_NUMPY_OFF.split()) <= known, set(_NUMPY_OFF.split()) - known


def test_opencv_knows_every_name_it_may_be_given():
    """OpenCV names an unknown feature in a warning and holds nothing: with every name of the table given,
    it may say a feature is unavailable here, never that one is unknown."""
    names = ",".join(name for name, _ in _OPENCV_AVX512)
    r = subprocess.run([sys.executable, "-c", "import cv2; cv2.getCPUFeaturesLine()"], capture_output=True,
                       text=True, env=dict(os.environ, OPENCV_CPU_DISABLE=names), timeout=60)
    assert r.returncode == 0, r.stderr
    assert "unknown CPU feature" not in r.stderr, r.stderr


@pytest.mark.skipif(platform.machine() != "x86_64" or not {"avx2", "fma"} <= cpu_flags(),
                    reason="the libraries are held only on an x86-64 CPU with AVX2 and FMA")
def test_the_command_and_what_it_starts_run_held_and_quietly():
    """``gflow --version`` says so; a process started as the stages are (inheriting the command's
    environment) has every switch, and OpenCV loads without a word on stderr."""
    env = {k: v for k, v in os.environ.items() if k not in HELD and k != "GFLOW_SIMD"}
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "--version"], capture_output=True, text=True, env=env,
                       cwd=ROOT, timeout=60)
    assert r.returncode == 0 and r.stdout.rstrip().endswith("; SIMD held to x86-64-v3)"), r.stdout + r.stderr
    inner = f"import os; print(sorted(k for k in os.environ if k in {list(HELD)!r}))"
    probe = ("import gflow, cv2, subprocess, sys; cv2.getCPUFeaturesLine(); "
             f"print(subprocess.run([sys.executable, '-c', {inner!r}], capture_output=True, text=True).stdout.strip())")
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=env, cwd=ROOT, timeout=60)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    expected = sorted(set(HELD) - ({"OPENCV_CPU_DISABLE"} if "avx512f" not in cpu_flags() else set()))
    assert r.stdout.strip() == str(expected)
    native = subprocess.run([sys.executable, "-m", "pipeline.cli", "--version"], capture_output=True, text=True,
                            env=dict(env, GFLOW_SIMD="native"), cwd=ROOT, timeout=60)
    assert native.stdout.rstrip().endswith("; SIMD native (GFLOW_SIMD=native))"), native.stdout


def test_a_mistyped_gflow_simd_is_a_one_line_mistake_before_any_work(tmp_path):
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "eval", "--gt", "x.csv", "--pred", "y.csv"],
                       capture_output=True, text=True, env=dict(os.environ, GFLOW_SIMD="nativ"), cwd=tmp_path,
                       timeout=60)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "GFLOW_SIMD must be 'native'" in lines[0] and "'nativ'" in lines[0], r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.skipif("avx512f" not in cpu_flags(), reason="this CPU has no AVX-512: no library can load with kernels "
                    "other than the held ones, so there is nothing to name")
def test_a_library_loaded_before_gflow_is_named_in_the_kernels_a_run_records():
    """numpy or OpenCV imported before gflow keeps the AVX-512 kernels it loaded with (each reads its switch when it
    loads), yet ``versions()['simd']``, which a recording keeps, said "SIMD held to x86-64-v3" all the same: a
    recording made so through the API re-ran under the commands with float differences, and `gflow rerun` saw no
    difference of versions to explain them. Now the loaded libraries are asked, and the difference is named."""
    env = {k: v for k, v in os.environ.items() if k not in HELD and k != "GFLOW_SIMD"}

    def simd(imports: str) -> str:
        code = f"{imports}; from pipeline.runtime.versions import versions; print(versions()['simd'])"
        r = subprocess.run([sys.executable, "-W", "ignore", "-c", code], capture_output=True, text=True, env=env,
                           cwd=ROOT, timeout=60)
        assert r.returncode == 0, r.stderr
        return r.stdout.strip()

    both_first, numpy_first, held = simd("import numpy, cv2, gflow"), simd("import numpy, gflow, cv2"), simd(
        "import gflow, numpy, cv2")
    assert both_first == "SIMD held to x86-64-v3, but numpy and OpenCV loaded before with AVX-512 kernels"
    assert numpy_first == "SIMD held to x86-64-v3, but numpy loaded before with AVX-512 kernels"
    assert held == "SIMD held to x86-64-v3"
    from pipeline.runtime.run_metadata import versions_differ

    assert versions_differ({"simd": numpy_first}, {"simd": held}) == [f"simd {numpy_first} -> {held}"]
