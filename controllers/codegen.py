"""Fast numeric evaluation of CasADi functions on the tick path.

CasADi's SX virtual machine takes ~60 µs for the two-UAV formation's Jacobians and creating DM
outputs another ~70 µs; the same function generated as C and compiled once takes ~1 µs.
``NumericFunction`` compiles with the system C compiler into a per-user cache (keyed by the
hash of the generated source, so a parameter change recompiles) and evaluates through
CasADi's buffer interface into preallocated dense arrays. Without a C compiler it falls
back to the virtual machine, with the same results.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
from pathlib import Path

import casadi as ca
import numpy as np

from geometry.arrays import FloatArray


def _cache_dir() -> Path:
    root = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(root) / "uavbar-supervisor" / f"casadi-{ca.CasadiMeta.version()}"


def compile_function(function: ca.Function) -> ca.Function:
    """``function`` as a compiled external, or itself when no C compiler is available."""
    compiler = shutil.which(os.environ.get("CC", "cc")) or shutil.which("gcc")
    if compiler is None:
        return function
    with tempfile.TemporaryDirectory() as scratch:
        generator = ca.CodeGenerator(f"{function.name()}.c", {"with_header": False})
        generator.add(function)
        generator.generate(scratch + os.sep)
        source = Path(scratch) / f"{function.name()}.c"
        digest = hashlib.sha256(source.read_bytes()).hexdigest()[:16]
        cache = _cache_dir()
        library = cache / f"{function.name()}_{digest}.so"
        if not library.exists():
            cache.mkdir(parents=True, exist_ok=True)
            partial = f".{library.stem}.{os.getpid()}"
            # CasADi's own JIT runs the compiler (its "shell" plugin); kept, not cleaned up,
            # and moved into place atomically so concurrent processes never load half a file.
            ca.Importer(
                str(source),
                "shell",
                {
                    "compiler": compiler,
                    "compiler_flags": ["-O2", "-fPIC"],
                    "directory": str(cache) + os.sep,
                    "name": partial,
                    "temp_suffix": False,
                    "cleanup": False,
                },
            )
            (cache / f"{partial}.so").replace(library)
            (cache / f"{partial}.o").unlink(missing_ok=True)
    return ca.external(function.name(), str(library))


class NumericFunction:
    """Evaluate a CasADi function of dense vector inputs into dense matrices, fast.

    The arrays returned by ``__call__`` are owned by this object and overwritten by the
    next call; copy them to keep them.
    """

    def __init__(self, function: ca.Function, compile_c: bool = True) -> None:
        self._function = compile_function(function) if compile_c else function
        self._buffer, self._evaluate = self._function.buffer()
        self._inputs = [np.zeros(function.size1_in(i)) for i in range(function.n_in())]
        self._nonzeros = [np.zeros(function.sparsity_out(i).nnz()) for i in range(function.n_out())]
        self._dense = [np.zeros(function.size_out(i)) for i in range(function.n_out())]
        # Flat positions of each output's nonzeros in its (row-major) dense array.
        self._positions = []
        for i, dense in enumerate(self._dense):
            rows, cols = function.sparsity_out(i).get_triplet()
            self._positions.append(np.ravel_multi_index((rows, cols), dense.shape))
        self._flat = [dense.reshape(-1) for dense in self._dense]
        # casadi's stubs declare a byte-size argument its binding rejects; the runtime form is
        # set_arg(i, memoryview). The arrays live as long as this object (the buffer keeps
        # raw pointers into them).
        for i, array in enumerate(self._inputs):
            self._buffer.set_arg(i, memoryview(array))  # type: ignore[call-arg, arg-type]
        for i, array in enumerate(self._nonzeros):
            self._buffer.set_res(i, memoryview(array))  # type: ignore[call-arg, arg-type]

    @property
    def compiled(self) -> bool:
        """Whether the compiled C version is in use."""
        return self._function.class_name() != "SXFunction"

    def __call__(self, *inputs: FloatArray) -> list[FloatArray]:
        for target, value in zip(self._inputs, inputs, strict=True):
            target[:] = value
        self._evaluate()
        for flat, nonzeros, positions in zip(
            self._flat, self._nonzeros, self._positions, strict=True
        ):
            flat[positions] = nonzeros
        return self._dense
