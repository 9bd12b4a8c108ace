"""Physical systems by the name a model configuration uses: a built-in or an import path.

``system: single_track`` names a built-in; ``system: mypackage.motors:DCMotor`` a user's
``LTIModel`` subclass in any importable module (``examples/user_system/``). Each system is
built for one block, given the block's name: systems with parameters of their own (a lag's time
constant) prefix them with it (``local_name``); the vehicle systems read the shared vehicle
parameters.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Iterator, Mapping

from hypa.core.plugins import plugins
from hypa.physics.contract import SystemContractError, check_system
from hypa.physics.curved import Curved, CurvedError
from hypa.physics.dependent import Dependent, DependentError, Driven
from hypa.physics.elements import FirstOrderLag, GainLag, LeadLag, SecondOrder, StaticGain
from hypa.physics.friction import MassWithCoulombFriction, MassWithCubicFriction, MassWithFriction
from hypa.physics.limited import Limited, LimitedError
from hypa.physics.lti import LTIModel
from hypa.physics.mass_spring_damper import DuffingOscillator, MassSpringDamper
from hypa.physics.modes import Moded
from hypa.physics.tanks import CascadedTanks, TorricelliTanks
from hypa.physics.wiener_hammerstein import WienerHammerstein

__all__ = ["PHYSICS_SYSTEMS", "SystemContractError", "build_system", "check_system", "is_import_path",
           "resolve_system"]

class SystemRegistry(Mapping):
    """Built-in systems by name: the core's generic ones, and those the domain packages register
    (the entry points ``hypa.systems``, :mod:`hypa.core.plugins`: the vehicle's). Those are read on
    first use, so the core never imports a domain."""

    def __init__(self, core: Mapping[str, Callable[[str], LTIModel]]) -> None:
        self._core = dict(core)
        self._systems: dict[str, Callable[[str], LTIModel]] | None = None

    def _all(self) -> dict[str, Callable[[str], LTIModel]]:
        if self._systems is None:
            systems = dict(self._core)
            for domain, registered in plugins("systems").items():
                clash = sorted(set(systems) & set(registered))
                if clash:
                    raise SystemContractError(f"the systems of {domain!r} (hypa.systems) take built-in names: "
                                              f"{', '.join(clash)}")
                systems.update(registered)
            self._systems = systems
        return self._systems

    def __getitem__(self, name: str) -> Callable[[str], LTIModel]:
        return self._all()[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._all())

    def __len__(self) -> int:
        return len(self._all())


PHYSICS_SYSTEMS = SystemRegistry({
    "first_order_lag": FirstOrderLag,  # τ ẏ = u - y, parameter <block>/tau_s
    "gain_lag": GainLag,  # τ ẏ = k u - y, parameters <block>/gain, <block>/tau_s
    "lead_lag": LeadLag,  # a gain with a transient part through a lag: <block>/gain, transient, transient_tau_s, tau_s
    "gain": StaticGain,  # y = k u, parameter <block>/gain
    # k (1 + T s) / (1 + 2ζ s/ω + s²/ω²): <block>/gain, zero_s, natural_frequency_hz, damping
    "second_order": SecondOrder,
    "mass_spring_damper": lambda block: MassSpringDamper(),  # force -> position (Silverbox)
    "duffing_oscillator": lambda block: DuffingOscillator(),  # the same with a cubic spring (nonlinear)
    "mass_with_friction": lambda block: MassWithFriction(),  # force -> position (EMPS)
    "mass_with_coulomb_friction": lambda block: MassWithCoulombFriction(),  # the same + Fc sign(v) (nonlinear)
    "mass_with_cubic_friction": lambda block: MassWithCubicFriction(),  # + a partly cubic viscous friction
    "cascaded_tanks": lambda block: CascadedTanks(),  # pump -> lower level, outflows linear (cascaded tanks)
    "torricelli_tanks": lambda block: TorricelliTanks(),  # the same through orifices, q = k h^a (nonlinear)
    # a filter, a knee (a one-sided saturation), a filter: <block>/first_frequency_hz, ..., knee, notch_damping
    "wiener_hammerstein": WienerHammerstein,
})


def is_import_path(name: str) -> bool:
    """Whether ``name`` is an import path ``package.module:Class`` rather than a built-in name."""
    return ":" in name


def resolve_system(name: str, block: str = "") -> LTIModel:
    """The system ``name`` (built-in or ``package.module:Class``) for the block ``block``.

    A user's class is instantiated with no arguments, or with ``block=`` when its ``__init__``
    takes it (to prefix block-local parameter names), and checked (``check_system``).
    Raises ``SystemContractError`` with one line saying what is wrong.
    """
    if not isinstance(name, str) or not name:
        raise SystemContractError(f"a system must be a built-in name or package.module:Class, got {name!r}")
    if not is_import_path(name):
        if name not in PHYSICS_SYSTEMS:
            raise SystemContractError(f"unknown physics system {name!r}; known: {', '.join(PHYSICS_SYSTEMS)}, "
                                      "or an import path package.module:Class")
        return PHYSICS_SYSTEMS[name](block)
    cls = _import_class(name)
    try:
        takes_block = "block" in inspect.signature(cls).parameters
    except (TypeError, ValueError):  # no introspectable signature: call it plainly
        takes_block = False
    try:
        system = cls(block=block) if takes_block else cls()
    except Exception as error:  # a user's constructor: one line, whatever it raised
        how = f"{cls.__name__}(block={block!r})" if takes_block else f"{cls.__name__}()"
        raise SystemContractError(f"system {name}: {how} raised {type(error).__name__}: {error}") from error
    check_system(system, name)
    return system


def build_system(name: str, block: str = "", curved: Mapping[str, int | str] | None = None,
                 limited: Mapping[str, str] | None = None, depends: Mapping[str, Mapping[str, str]] | None = None,
                 driven: tuple[str, ...] = (), modes: tuple[str, ...] = ()) -> LTIModel:
    """The system ``name`` for the block ``block`` (``resolve_system``), its couplings from the
    states of ``curved`` (state -> power, a block's ``curved:``) bent (``hypa.physics.curved``),
    the states of ``limited`` (state -> upper | lower) held at a limit (``hypa.physics.limited``),
    the parameters of ``depends`` varying with a direction or a state and the signals of
    ``driven`` entering its state derivatives (``hypa.physics.dependent``), and a mode added per
    input of ``modes`` (``hypa.physics.modes``)."""
    system = resolve_system(name, block)
    try:
        system = Moded(system, tuple(modes), block) if modes else system  # first: its states are the block's
        system = Curved(system, curved, block) if curved else system
        system = Limited(system, limited, block) if limited else system
        system = Dependent(system, depends, block) if depends else system
        return Driven(system, tuple(driven), block) if driven else system
    except (CurvedError, LimitedError, DependentError) as error:
        raise SystemContractError(f"block {block!r} ({name}): {error}") from None


def _import_class(path: str) -> type[LTIModel]:
    module_name, _, attribute = path.partition(":")
    if not module_name or not attribute:
        raise SystemContractError(f"system {path!r}: an import path is package.module:Class")
    try:
        module = importlib.import_module(module_name)
    except ImportError as error:
        raise SystemContractError(f"system {path}: cannot import module {module_name!r} ({error}); "
                                  "is its folder on the Python path?") from error
    except Exception as error:  # the module itself failed while running
        raise SystemContractError(f"system {path}: importing {module_name!r} raised "
                                  f"{type(error).__name__}: {error}") from error
    obj: object = module
    for part in attribute.split("."):
        if not hasattr(obj, part):
            defined = sorted(k for k, v in vars(module).items()
                             if isinstance(v, type) and issubclass(v, LTIModel) and v is not LTIModel)
            raise SystemContractError(f"system {path}: module {module_name!r} has no attribute {attribute!r}; "
                                      f"LTIModel classes there: {', '.join(defined) or 'none'}")
        obj = getattr(obj, part)
    if not (isinstance(obj, type) and issubclass(obj, LTIModel)):
        raise SystemContractError(f"system {path}: {attribute} is not a subclass of hypa.physics.LTIModel")
    if inspect.isabstract(obj):
        missing = ", ".join(sorted(obj.__abstractmethods__))
        raise SystemContractError(f"system {path}: {attribute} does not define {missing}")
    return obj
