"""One FMU instance behind one vocabulary, FMI 2.0 or 3.0: what ``hypa.physics.fmu.FMUSimulator`` calls.

fmpy's importers differ between the versions (``fmi2SetReal`` and ``fmi3SetFloat64``, ``fmi2SetupExperiment``
folded into FMI 3.0's ``fmi3EnterInitializationMode``, ``fmi2NewDiscreteStates`` and
``fmi3UpdateDiscreteStates``, FMI 3.0's ``fmi3DoStep`` reporting events and early returns, no input
derivatives in FMI 3.0). ``Instance`` holds either and offers the calls the simulator makes, by what they
do. FMI 3.0 is read as its Float64 variables (the ones FMI 2.0 calls Real).
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from typing import Any

import numpy as np


class Instance:
    """An instantiated FMU for ``interface`` (``model_exchange`` or ``co_simulation``) of FMI ``version`` 2 or
    3, unzipped in ``folder``; ``dll`` and ``component`` for the C loops (``hypa.physics.fmu_loop``)."""

    def __init__(self, version: int, interface: str, guid: str, folder: str, identifier: str, name: str) -> None:
        if version == 3:
            from fmpy.fmi3 import FMU3Model as Model
            from fmpy.fmi3 import FMU3Slave as Slave
        else:
            from fmpy.fmi2 import FMU2Model as Model
            from fmpy.fmi2 import FMU2Slave as Slave
        kind = Model if interface == "model_exchange" else Slave
        self.version, self.interface = version, interface
        self.fmu: Any = kind(guid=guid, unzipDirectory=folder, modelIdentifier=identifier, instanceName=name)
        self.fmu.instantiate()

    @property
    def dll(self) -> Any:
        return self.fmu.dll

    @property
    def component(self) -> Any:
        return self.fmu.component

    def reset(self) -> None:
        self.fmu.reset()

    def set_reals(self, references: Sequence[int], values: Sequence[float]) -> None:
        (self.fmu.setFloat64 if self.version == 3 else self.fmu.setReal)(list(references), list(values))

    def get_reals(self, references: Sequence[int]) -> list[float]:
        return (self.fmu.getFloat64 if self.version == 3 else self.fmu.getReal)(list(references))

    def initialize(self, t0: float) -> None:
        """The experiment set up at ``t0`` and initialization mode entered."""
        if self.version == 3:
            self.fmu.enterInitializationMode(startTime=t0)
        else:
            self.fmu.setupExperiment(startTime=t0)
            self.fmu.enterInitializationMode()

    def exit_initialization(self) -> None:
        self.fmu.exitInitializationMode()

    def discrete_states(self) -> tuple[bool, bool, bool, float]:
        """One step of the event iteration: (another needed, terminate, a time event scheduled, its time)."""
        if self.version == 3:
            needed, terminate, _, _, timed, at = self.fmu.updateDiscreteStates()
        else:
            needed, terminate, _, _, timed, at = self.fmu.newDiscreteStates()
        return bool(needed), bool(terminate), bool(timed), float(at)

    def enter_continuous_time_mode(self) -> None:
        self.fmu.enterContinuousTimeMode()

    def set_time(self, t: float) -> None:
        self.fmu.setTime(t)

    def set_states(self, x: Any, n: int) -> None:
        self.fmu.setContinuousStates(x, n)

    def get_states(self, x: Any, n: int) -> None:
        self.fmu.getContinuousStates(x, n)

    def get_derivatives(self, dx: Any, n: int) -> None:
        (self.fmu.getContinuousStateDerivatives if self.version == 3 else self.fmu.getDerivatives)(dx, n)

    def get_event_indicators(self, z: Any, n: int) -> None:
        self.fmu.getEventIndicators(z, n)

    def completed_step(self) -> tuple[bool, bool]:
        """fmi2/3CompletedIntegratorStep: (enter event mode, terminate)."""
        # hypa may set earlier states afterwards (the sensitivities): noSetFMUStatePriorToCurrentPoint is false
        event, terminate = self.fmu.completedIntegratorStep(noSetFMUStatePriorToCurrentPoint=False)[:2]
        return bool(event), bool(terminate)

    def directional(self, unknowns: Sequence[int], knowns: Sequence[int], seed: Sequence[float]) -> np.ndarray:
        return np.asarray(self.fmu.getDirectionalDerivative(list(unknowns), list(knowns), list(seed)), dtype=float)

    def do_step(self, t: float, h: float) -> str:
        """One co-simulation step; '' where it completed, else why not (an early return, a request to terminate:
        FMI 3.0 says so), in ``hypa.physics.fmu_loop.EVENTS``' words."""
        if self.version == 3:
            from hypa.physics.fmu_loop import EVENTS

            _, terminate, early, _ = self.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)
            return EVENTS[12] if terminate else EVENTS[13] if early else ""
        self.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)
        return ""

    def set_input_derivatives(self, references: Sequence[int], slopes: Sequence[float]) -> None:
        """FMI 2.0 co-simulation: first derivatives of the inputs over the next step."""
        self.fmu.setRealInputDerivatives(list(references), [1] * len(references), list(slopes))

    def close(self) -> None:
        with contextlib.suppress(Exception):  # terminating an instance that failed: nothing more to do
            self.fmu.terminate()
        self.fmu.freeInstance()
