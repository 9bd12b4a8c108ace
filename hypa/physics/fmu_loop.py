"""The FMU block's sample loop in C: every call into the FMU from C, none through Python.

``FMUSimulator`` (``hypa.physics.fmu``) runs its loops over the samples here where the machine has a C
compiler (cc, gcc or clang): ``c/fmu_loop.c``, compiled once per process into a private temporary folder and
loaded with ctypes, calls the FMU's own functions (FMI 2.0's ``fmi2SetTime``, ``fmi2SetContinuousStates``,
``fmi2SetReal``, ``fmi2GetDerivatives``, ``fmi2GetReal``, ``fmi2CompletedIntegratorStep``,
``fmi2GetEventIndicators``, ``fmi2DoStep``, ``fmi2SetRealInputDerivatives``, and FMI 3.0's own)
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
from pathlib import Path
from typing import Any

import numpy as np

from hypa.core.compiler import c_compiler, compile_c

log = logging.getLogger(__name__)

SOURCE = Path(__file__).with_name("c") / "fmu_loop.c"
FAILED = -1
# fmu_loop.c's FAILED_* and EVENT_*: the call (FMI 2.0, FMI 3.0) that failed, or the event that stopped the loop
CALLS = {1: ("fmi2SetTime", "fmi3SetTime"), 2: ("fmi2SetContinuousStates", "fmi3SetContinuousStates"),
         3: ("fmi2SetReal", "fmi3SetFloat64"), 4: ("fmi2GetDerivatives", "fmi3GetContinuousStateDerivatives"),
         5: ("fmi2GetReal", "fmi3GetFloat64"), 6: ("fmi2DoStep", "fmi3DoStep"),
         7: ("fmi2SetRealInputDerivatives", ""), 8: ("fmi2CompletedIntegratorStep", "fmi3CompletedIntegratorStep"),
         9: ("fmi2GetEventIndicators", "fmi3GetEventIndicators")}
EVENTS = {10: "an event indicator changed sign: a state event, which hypa's integration of model exchange does not "
              "handle (use the FMU's co-simulation interface)",
          11: "it asked for event mode after a completed step, which hypa's integration of model exchange does not "
              "handle (use the FMU's co-simulation interface)",
          12: "it asked to terminate the simulation",
          13: "it returned early from a co-simulation step (an event inside it)"}
_DOUBLES = ctypes.POINTER(ctypes.c_double)


class _Api(ctypes.Structure):
    """``hypa_fmu`` of fmu_loop.c: the FMU's component and functions, the sizes, the value references and
    the scratch."""

    _fields_ = [("component", ctypes.c_void_p), *((name, ctypes.c_void_p) for name in (
        "set_time", "set_states", "set_real", "get_derivatives", "get_real", "do_step", "set_input_derivatives",
        "completed_step", "get_event_indicators")),
        ("version", ctypes.c_int), ("n", ctypes.c_int), ("m", ctypes.c_int), ("p", ctypes.c_int), ("e", ctypes.c_int),
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
    folder: Path | None = None
    try:
        folder = Path(tempfile.mkdtemp(prefix="hypa-fmu-loop-"))  # private (0700): nothing else can swap it
        library = folder / "fmu_loop.so"
        # -ffp-contract=off: no fused multiply-adds (clang's default), so the C loops keep the Python loops' numbers
        error = compile_c([cc, "-O2", "-std=c99", "-ffp-contract=off", "-shared", "-fPIC", "-o", str(library),
                           str(SOURCE), "-lm"], folder)
        loaded = None if error else ctypes.CDLL(str(library))
    except OSError as failure:  # no temporary folder, or one mounted noexec
        error, loaded = str(failure).splitlines()[0] if str(failure) else type(failure).__name__, None
    finally:  # loaded, the library is mapped: its file is not needed (nor left behind by a forked worker)
        if folder is not None:
            shutil.rmtree(folder, ignore_errors=True)
    if loaded is None:
        log.info("the FMU block's C loop does not build or load here (%s): FMU blocks call their FMU through Python, "
                 "about a hundred times slower", error)
        return None
    for name in ("hypa_me_run", "hypa_me_sensitivities", "hypa_cs_run"):
        getattr(loaded, name).restype = ctypes.c_int
    return loaded


def available() -> bool:
    """Whether the C loop runs here."""
    return _library() is not None


def _pointer(array: np.ndarray) -> Any:
    return array.ctypes.data_as(_DOUBLES)


# the functions the loops call, by FMI version; None: not called in that version
FUNCTIONS = {
    2: {"set_time": "fmi2SetTime", "set_states": "fmi2SetContinuousStates", "set_real": "fmi2SetReal",
        "get_derivatives": "fmi2GetDerivatives", "get_real": "fmi2GetReal", "do_step": "fmi2DoStep",
        "set_input_derivatives": "fmi2SetRealInputDerivatives", "completed_step": "fmi2CompletedIntegratorStep",
        "get_event_indicators": "fmi2GetEventIndicators"},
    3: {"set_time": "fmi3SetTime", "set_states": "fmi3SetContinuousStates", "set_real": "fmi3SetFloat64",
        "get_derivatives": "fmi3GetContinuousStateDerivatives", "get_real": "fmi3GetFloat64", "do_step": "fmi3DoStep",
        "set_input_derivatives": None, "completed_step": "fmi3CompletedIntegratorStep",
        "get_event_indicators": "fmi3GetEventIndicators"},
}


class FMULoop:
    """The C loops bound to one FMU instance (an fmpy ``FMU2Model``, ``FMU2Slave``, ``FMU3Model`` or
    ``FMU3Slave`` of FMI ``version`` 2 or 3), its ``n`` states and ``events`` event indicators (model exchange:
    a free run stops where one changes sign), the value references of the inputs it feeds and the outputs it
    reads; ``completed``: model exchange, where each sample ends a completed integrator step. ``LoopError``
    where a call fails or an event stops it."""

    def __init__(self, fmu: Any, version: int, n: int, inputs: list[int], outputs: list[int], events: int = 0,
                 completed: bool = False) -> None:
        library = _library()
        if library is None:
            raise RuntimeError("the FMU loop did not compile here")
        self.library, self.version = library, version
        dll = fmu.dll

        def address(name: str | None) -> int | None:
            return ctypes.cast(getattr(dll, name), ctypes.c_void_p).value if name and hasattr(dll, name) else None

        functions = {key: address(name) for key, name in FUNCTIONS[version].items()}
        if not completed:
            functions["completed_step"] = functions["get_event_indicators"] = None
            events = 0
        self._inputs = (ctypes.c_uint * max(len(inputs), 1))(*inputs)
        self._outputs = (ctypes.c_uint * max(len(outputs), 1))(*outputs)
        m, p = len(inputs), len(outputs)
        self._work = np.zeros(9 * n + 4 * m + p + 2 * events + 1)
        self._order = (ctypes.c_int * max(m, 1))()
        self.api = _Api(component=ctypes.cast(fmu.component, ctypes.c_void_p).value, **functions, version=version,
                        n=n, m=m, p=p, e=events, inputs=self._inputs, outputs=self._outputs,
                        work=_pointer(self._work), order=self._order)
        self.n, self.m, self.p = n, m, p

    def _check(self, status: int) -> None:
        if status == FAILED:
            code = int(self.api.failed)
            what = EVENTS.get(code) or f"{CALLS.get(code, ('a call', 'a call'))[self.version - 2]} failed"
            raise LoopError(what, int(self.api.at))

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
    """A call into the FMU that returned Discard, Error or Fatal, or an event the loop does not handle: what
    (``what``), and at which sample."""

    def __init__(self, what: str, sample: int) -> None:
        super().__init__(f"{what} at sample {sample}")
        self.what, self.sample = what, sample
