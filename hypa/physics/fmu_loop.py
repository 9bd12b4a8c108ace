"""The FMU block's sample loop in C: every call into the FMU from C, none through Python.

``FMUSimulator`` (``hypa.physics.fmu``) runs its loops over the samples here where the machine has a C
compiler (cc, gcc or clang): ``c/fmu_loop.c``, compiled once per process into a private temporary folder and
loaded with ctypes, calls the FMU's own functions (``fmi2SetTime``, ``fmi2SetContinuousStates``,
``fmi2SetReal``, ``fmi2GetDerivatives``, ``fmi2GetReal``, ``fmi2DoStep``, ``fmi2SetRealInputDerivatives``)
with the arithmetic of the Python loops, so both give the same numbers; a Python call into an FMU through
fmpy costs microseconds, the C call tens of nanoseconds. Without a compiler (or where it fails) the Python
loops run, said once in one line.
"""

from __future__ import annotations

import ctypes
import functools
import logging
import shutil
import sys
import tempfile
import weakref
from pathlib import Path
from typing import Any

import numpy as np

from hypa.core.compiler import c_compiler, compile_c

log = logging.getLogger(__name__)

SOURCE = Path(__file__).with_name("c") / "fmu_loop.c"
FAILED = -1
CALLS = {1: "fmi2SetTime", 2: "fmi2SetContinuousStates", 3: "fmi2SetReal", 4: "fmi2GetDerivatives",
         5: "fmi2GetReal", 6: "fmi2DoStep", 7: "fmi2SetRealInputDerivatives"}
_DOUBLES = ctypes.POINTER(ctypes.c_double)


class _Api(ctypes.Structure):
    """``hypa_fmu`` of fmu_loop.c: the FMU's component and functions, the sizes, the value references and
    the scratch."""

    _fields_ = [("component", ctypes.c_void_p), *((name, ctypes.c_void_p) for name in (
        "set_time", "set_states", "set_real", "get_derivatives", "get_real", "do_step", "set_input_derivatives")),
        ("n", ctypes.c_int), ("m", ctypes.c_int), ("p", ctypes.c_int),
        ("inputs", ctypes.POINTER(ctypes.c_uint)), ("outputs", ctypes.POINTER(ctypes.c_uint)),
        ("work", _DOUBLES), ("order", ctypes.POINTER(ctypes.c_int)),
        ("failed", ctypes.c_int), ("at", ctypes.c_long)]


@functools.cache
def _library() -> ctypes.CDLL | None:
    """fmu_loop.c compiled and loaded (once per process), or None where no compiler builds it."""
    cc = c_compiler()
    if cc is None or sys.platform == "win32":
        log.info("no C compiler (cc, gcc, clang) on PATH: FMU blocks call their FMU through Python, about a "
                 "hundred times slower")
        return None
    folder = Path(tempfile.mkdtemp(prefix="hypa-fmu-loop-"))  # private (0700): nothing else can swap the library
    library = folder / "fmu_loop.so"
    error = compile_c([cc, "-O2", "-std=c99", "-shared", "-fPIC", "-o", str(library), str(SOURCE), "-lm"], folder)
    if error:
        shutil.rmtree(folder, ignore_errors=True)
        log.info("the FMU block's C loop does not compile here (%s): FMU blocks call their FMU through Python, about "
                 "a hundred times slower", error)
        return None
    loaded = ctypes.CDLL(str(library))
    weakref.finalize(loaded, shutil.rmtree, folder, True)
    for name in ("hypa_me_run", "hypa_me_sensitivities", "hypa_cs_run"):
        getattr(loaded, name).restype = ctypes.c_int
    return loaded


def available() -> bool:
    """Whether the C loop runs here."""
    return _library() is not None


def _pointer(array: np.ndarray) -> Any:
    return array.ctypes.data_as(_DOUBLES)


class FMULoop:
    """The C loops bound to one FMU instance (an fmpy ``FMU2Model`` or ``FMU2Slave``), its ``n`` states, the
    value references of the inputs it feeds and the outputs it reads. ``LoopError`` where a call fails."""

    def __init__(self, fmu: Any, n: int, inputs: list[int], outputs: list[int]) -> None:
        library = _library()
        if library is None:
            raise RuntimeError("the FMU loop did not compile here")
        self.library = library
        dll = fmu.dll
        address = lambda name: ctypes.cast(getattr(dll, name), ctypes.c_void_p).value  # noqa: E731
        optional = lambda name: address(name) if hasattr(dll, name) else None  # noqa: E731
        self._inputs = (ctypes.c_uint * max(len(inputs), 1))(*inputs)
        self._outputs = (ctypes.c_uint * max(len(outputs), 1))(*outputs)
        m, p = len(inputs), len(outputs)
        self._work = np.zeros(9 * n + 4 * m + p + 1)
        self._order = (ctypes.c_int * max(m, 1))()
        self.api = _Api(component=ctypes.cast(fmu.component, ctypes.c_void_p).value,
                        set_time=optional("fmi2SetTime"), set_states=optional("fmi2SetContinuousStates"),
                        set_real=address("fmi2SetReal"), get_derivatives=optional("fmi2GetDerivatives"),
                        get_real=address("fmi2GetReal"), do_step=optional("fmi2DoStep"),
                        set_input_derivatives=optional("fmi2SetRealInputDerivatives"),
                        n=n, m=m, p=p, inputs=self._inputs, outputs=self._outputs, work=_pointer(self._work),
                        order=self._order)
        self.n, self.m, self.p = n, m, p

    def _check(self, status: int) -> None:
        if status == FAILED:
            raise LoopError(CALLS.get(self.api.failed, "a call"), int(self.api.at))

    def exchange(self, u: np.ndarray, t0: float, dt: float, count: int, foh: bool, x: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Model exchange from x (n,): outputs (T, p) and states (T, n) for inputs u (T, m), all SI."""
        u = np.ascontiguousarray(u, dtype=np.float64)
        steps = len(u)
        x = np.array(x, dtype=np.float64)
        y, xs = np.empty((steps, self.p)), np.empty((steps, self.n))
        self._check(self.library.hypa_me_run(ctypes.byref(self.api), _pointer(u), ctypes.c_long(steps),
                                             ctypes.c_double(t0), ctypes.c_double(dt), ctypes.c_int(count),
                                             ctypes.c_int(int(foh)), _pointer(x), _pointer(y), _pointer(xs)))
        return y, xs

    def sensitivities(self, u: np.ndarray, t0: float, dt: float, count: int, foh: bool, xs: np.ndarray,
                      ys: np.ndarray) -> tuple[np.ndarray, ...]:
        """∂y_k/∂x_k, ∂y_k/∂u_k, ∂x_k+1/∂x_k, ∂x_k+1/∂u_k, ∂x_k+1/∂u_k+1 of a model-exchange run (xs, ys)."""
        u = np.ascontiguousarray(u, dtype=np.float64)
        xs, ys = np.ascontiguousarray(xs, dtype=np.float64), np.ascontiguousarray(ys, dtype=np.float64)
        steps, n, m, p = len(u), self.n, self.m, self.p
        out = (np.zeros((steps, p, n)), np.zeros((steps, p, m)), np.zeros((steps, n, n)), np.zeros((steps, n, m)),
               np.zeros((steps, n, m)))
        self._check(self.library.hypa_me_sensitivities(
            ctypes.byref(self.api), _pointer(u), ctypes.c_long(steps), ctypes.c_double(t0), ctypes.c_double(dt),
            ctypes.c_int(count), ctypes.c_int(int(foh)), _pointer(xs), _pointer(ys), *map(_pointer, out)))
        return out

    def cosimulate(self, u: np.ndarray, t0: float, dt: float, foh: bool) -> np.ndarray:
        """Co-simulation: outputs (T, p) for inputs u (T, m), SI."""
        u = np.ascontiguousarray(u, dtype=np.float64)
        y = np.empty((len(u), self.p))
        self._check(self.library.hypa_cs_run(ctypes.byref(self.api), _pointer(u), ctypes.c_long(len(u)),
                                             ctypes.c_double(t0), ctypes.c_double(dt), ctypes.c_int(int(foh)),
                                             _pointer(y)))
        return y


class LoopError(RuntimeError):
    """A call into the FMU that returned fmi2Discard, fmi2Error or fmi2Fatal: which, and at which sample."""

    def __init__(self, call: str, sample: int) -> None:
        super().__init__(f"{call} failed at sample {sample}")
        self.call, self.sample = call, sample
