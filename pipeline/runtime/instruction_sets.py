"""The same bits on every x86-64 machine: numpy, OpenCV and OpenBLAS held to x86-64-v3 (AVX2, FMA).

numpy, OpenCV (its own kernels and Intel IPP's) and OpenBLAS choose their SIMD kernels when they load,
from the CPU they find. Kernels for different instruction sets round differently in the last bits
(numpy's AVX-512 exp and log, OpenBLAS's SkylakeX GEMM, OpenCV's AVX512-SKX dispatch), and the
trackers' particle filters and online models carry a difference in the last bit into a different
track. Measured on one machine (AVX2), dcf on caviar1, seed 1: AUC 0.851 as it is, 0.834 with numpy
held to SSE4.2 (``NPY_DISABLE_CPU_FEATURES=X86_V3``) and 0.858 with OpenCV's dispatch held to SSE4.2;
OpenBLAS's Sandybridge kernels and IPP held to AVX2 left it bit for bit the same. So a recording made
on a machine with AVX-512 would not re-run bit for bit on one without, and a figure measured on one
kind of machine would not be reproduced on another.

:func:`hold` therefore sets, for the process and every process it starts, the libraries' own
switches to the instruction sets of x86-64-v3, which every x86-64 server CPU of the last decade
has: ``NPY_DISABLE_CPU_FEATURES`` (numpy's AVX-512 groups off), ``OPENCV_CPU_DISABLE`` (the AVX-512
features this CPU has, named as OpenCV names them, so OpenCV warns of none), ``OPENCV_IPP=avx2`` and
``OPENBLAS_CORETYPE=Haswell``. On a machine without AVX-512 that changes no kernel; on one with
AVX-512 the code runs somewhat slower where those kernels were faster. A variable the user set is
left as it is; ``GFLOW_SIMD=native`` leaves all four to the libraries. On a CPU without AVX2 and FMA,
or not x86-64, nothing is held (there is no common level to hold to).

Each switch is read when its library loads, so :func:`hold` must run before the first import of
numpy, cv2 or scipy: the ``gflow`` command calls it first thing, and ``import gflow`` does before
its own imports (and warns, on a machine with AVX-512, when numpy was imported before it).
Not verified here: a machine with AVX-512 giving the same bits as one without (none was available
when this was written); what was measured is above.
"""

from __future__ import annotations

import os
import platform
import sys
from collections.abc import MutableMapping
from pathlib import Path

__all__ = ["hold", "cpu_flags", "HELD", "described", "check_setting", "loaded_unheld"]

# numpy >= 2.4 names its x86 dispatch targets by level: X86_V4 is AVX-512 (Skylake-X), the other two
# later AVX-512 generations
_NUMPY_OFF = "X86_V4 AVX512_ICL AVX512_SPR"

# OpenCV's names (modules/core/src/system.cpp) of the AVX-512 features and of the groups it derives
# from them, with the /proc/cpuinfo flags each needs: OpenCV warns of a name the CPU lacks, so only
# those it has are named
_F, _CD, _BW, _DQ, _VL = "avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl"
_SKX = {_F, _CD, _BW, _DQ, _VL}
_OPENCV_AVX512: tuple[tuple[str, frozenset[str]], ...] = tuple((name, frozenset(needs)) for name, needs in (
    ("AVX512F", {_F}), ("AVX512CD", {_CD}), ("AVX512BW", {_BW}), ("AVX512DQ", {_DQ}), ("AVX512VL", {_VL}),
    ("AVX512IFMA", {"avx512ifma"}), ("AVX512VBMI", {"avx512vbmi"}), ("AVX512VBMI2", {"avx512_vbmi2"}),
    ("AVX512VNNI", {"avx512_vnni"}), ("AVX512BITALG", {"avx512_bitalg"}),
    ("AVX512VPOPCNTDQ", {"avx512_vpopcntdq"}), ("AVX512ER", {"avx512er"}), ("AVX512PF", {"avx512pf"}),
    ("AVX5124VNNIW", {"avx512_4vnniw"}), ("AVX5124FMAPS", {"avx512_4fmaps"}),
    ("AVX512-COMMON", {_F, _CD}), ("AVX512-SKX", _SKX),
    ("AVX512-CNL", _SKX | {"avx512ifma", "avx512vbmi"}), ("AVX512-CLX", _SKX | {"avx512_vnni"}),
    ("AVX512-ICL", _SKX | {"avx512ifma", "avx512vbmi", "avx512_vnni", "avx512_vbmi2", "avx512_bitalg",
                           "avx512_vpopcntdq"}),
    ("AVX512-KNL", {_F, _CD, "avx512er", "avx512pf"}),
))

HELD = ("NPY_DISABLE_CPU_FEATURES", "OPENCV_CPU_DISABLE", "OPENCV_IPP", "OPENBLAS_CORETYPE")


def cpu_flags(cpuinfo: Path = Path("/proc/cpuinfo")) -> frozenset[str]:
    """The first CPU's ``flags`` in ``/proc/cpuinfo`` (empty where there is no such file)."""
    try:
        with open(cpuinfo, encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("flags"):
                    return frozenset(line.partition(":")[2].split())
    except OSError:
        pass
    return frozenset()


def _numpy_names_levels() -> bool:
    """Whether the installed numpy (read from its dist-info folder, without importing it) is 2.4 or
    later, which names its dispatch targets X86_V3, X86_V4, ..."""
    for entry in map(Path, sys.path):
        try:
            found = sorted(entry.glob("numpy-*.dist-info"))
        except OSError:
            continue
        if found:
            version = found[-1].name[len("numpy-"):-len(".dist-info")].split(".")
            try:
                return (int(version[0]), int(version[1])) >= (2, 4)
            except (IndexError, ValueError):
                return False
    return False


def check_setting(environ: MutableMapping[str, str] | None = None) -> None:
    """A ValueError naming ``GFLOW_SIMD`` when it is set to anything but ``native`` (a mistyped value would
    otherwise hold the kernels without a word)."""
    value = (os.environ if environ is None else environ).get("GFLOW_SIMD", "").strip()
    if value and value.lower() != "native":
        raise ValueError(f"GFLOW_SIMD must be 'native' (or unset, to hold the SIMD kernels), got {value!r}")


def hold(environ: MutableMapping[str, str] | None = None, flags: frozenset[str] | None = None,
         machine: str | None = None) -> dict[str, str]:
    """Set the four switches (see the module's docstring) in ``environ`` (``os.environ``: this process
    and those it starts), each only where it is not set already. Returns what it set. A ``GFLOW_SIMD`` other
    than ``native`` holds them too; :func:`check_setting` says it is a mistake (the ``gflow`` command does, before
    any work)."""
    env = os.environ if environ is None else environ
    if env.get("GFLOW_SIMD", "").strip().lower() == "native":
        return {}
    if (machine or platform.machine()).lower() not in ("x86_64", "amd64"):
        return {}
    flags = cpu_flags() if flags is None else flags
    if not {"avx2", "fma"} <= flags:
        return {}
    wanted = {"OPENCV_IPP": "avx2", "OPENBLAS_CORETYPE": "Haswell"}
    if _numpy_names_levels():
        wanted["NPY_DISABLE_CPU_FEATURES"] = _NUMPY_OFF
    opencv_off = [name for name, needs in _OPENCV_AVX512 if needs <= flags]
    if opencv_off:
        wanted["OPENCV_CPU_DISABLE"] = ",".join(opencv_off)
    done = {}
    for key, value in wanted.items():
        if key not in env:
            env[key] = value
            done[key] = value
    return done


def described(environ: MutableMapping[str, str] | None = None) -> str:
    """One line for ``gflow --version``, the figures' "Measured on" lines and a recording's ``gflow.versions``:
    ``x86-64-v3 held`` where :func:`hold` holds the libraries (and which loaded before it with AVX-512 kernels
    all the same: :func:`loaded_unheld`), ``native`` where it was told not to, else what is set."""
    env = os.environ if environ is None else environ
    if env.get("GFLOW_SIMD", "").strip().lower() == "native":
        return "SIMD native (GFLOW_SIMD=native)"
    if env.get("OPENBLAS_CORETYPE") == "Haswell" and env.get("OPENCV_IPP") == "avx2":
        early = loaded_unheld()
        if early:  # the switches came after these loaded: their kernels are the CPU's own
            return f"SIMD held to x86-64-v3, but {' and '.join(early)} loaded before with AVX-512 kernels"
        return "SIMD held to x86-64-v3"
    return "SIMD as the libraries choose"


def loaded_unheld() -> list[str]:
    """The libraries this process has loaded already whose AVX-512 kernels are on (["numpy", "OpenCV"]): each reads
    its switch when it loads, so one imported before :func:`hold` ran keeps the kernels the CPU offers, whatever
    the switches now say (``import numpy`` before ``import gflow``). Asks the loaded libraries themselves
    (numpy's ``__cpu_features__``, OpenCV's ``checkHardwareSupport``) and imports none; [] on a CPU without
    AVX-512."""
    out = []
    np_core = sys.modules.get("numpy._core._multiarray_umath") or sys.modules.get("numpy.core._multiarray_umath")
    if np_core is not None and getattr(np_core, "__cpu_features__", {}).get("AVX512_SKX"):
        out.append("numpy")
    cv2 = sys.modules.get("cv2")
    check = getattr(cv2, "checkHardwareSupport", None)
    try:
        if check is not None and check(_CV_CPU_AVX_512F):
            out.append("OpenCV")
    except Exception:  # noqa: BLE001  (an OpenCV without the check: nothing known, nothing claimed)
        pass
    return out


#: OpenCV's ``CPU_AVX_512F`` (modules/core/include/opencv2/core/cvdef.h), which its Python module does not export
_CV_CPU_AVX_512F = 13
