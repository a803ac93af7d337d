"""Which HPIPM/BLASFEO build the HPIPM back-end loads.

The casadi wheel ships both libraries built for BLASFEO's GENERIC target (plain C, no
SIMD): about 0.5 ms per interior-point iteration on the centralized problem. acados'
distribution of the same libraries for x86-64 is built for X64_INTEL_HASWELL (AVX2 + FMA
kernels) and is about 4× faster on the same QPs. ``supervisor/cli/hpipm_install.py`` places
that build in the virtualenv (``make`` runs it); it is used when present and the CPU has
AVX2 and FMA (elsewhere its kernels would fault), else casadi's build.
``UAVBAR_HPIPM_DIR`` names a folder holding ``libblasfeo.so`` and ``libhpipm.so`` to use
instead of both.

Only one build may live in a process (they export the same symbols), so the choice is
made once, at the first load.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import casadi

OPTIMIZED_DIR = Path(sys.prefix) / "lib" / "uavbar-hpipm"
"""Where ``supervisor/cli/hpipm_install.py`` puts the AVX2 build."""
LIBRARIES = ("libblasfeo.so", "libhpipm.so")
_NEEDED_CPU_FLAGS = frozenset({"avx2", "fma"})


def cpu_flags() -> frozenset[str]:
    """The CPU's feature flags (Linux ``/proc/cpuinfo``; empty where unreadable)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return frozenset()
    for line in text.splitlines():
        if line.startswith("flags"):
            return frozenset(line.partition(":")[2].split())
    return frozenset()


def _complete(folder: Path) -> bool:
    return all((folder / name).is_file() for name in LIBRARIES)


def library_folder() -> Path:
    """The folder to load ``libblasfeo.so`` and ``libhpipm.so`` from (see the docstring).
    Raises ``FileNotFoundError`` when ``UAVBAR_HPIPM_DIR`` lacks either library."""
    override = os.environ.get("UAVBAR_HPIPM_DIR")
    if override:
        folder = Path(override)
        if not _complete(folder):
            missing = " or ".join(LIBRARIES)
            raise FileNotFoundError(f"UAVBAR_HPIPM_DIR={override} lacks {missing}")
        return folder
    if _complete(OPTIMIZED_DIR) and cpu_flags() >= _NEEDED_CPU_FLAGS:
        return OPTIMIZED_DIR
    return Path(casadi.__file__).parent
