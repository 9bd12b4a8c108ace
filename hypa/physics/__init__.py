"""Known physics as normalized, lifted LTI state-space blocks in plain PyTorch.

parameters -> continuous A(θ), B(θ) (``LTIModel``) -> hold (``discretize``) -> eq. 5-8
(``normalize``) -> eq. 9-11 (``lifted_matrices``), wrapped by ``LTIBlock``, which does the
hold and eq. 5-8 in one matrix exponential (``normalized.NormalizingMaps``). A system is a
built-in or a user's ``LTIModel`` subclass named by import path (``systems.resolve_system``).
A block runs in ``simulation`` (outputs, states, steady and estimated states: ``estimation``);
scheduled parameters, varying per sample with a measured signal, in ``scheduled``.
"""

from hypa.physics.contract import SystemContractError, check_system
from hypa.physics.discretization import HOLDS, DiscreteLTI, discretize
from hypa.physics.elements import FirstOrderLag
from hypa.physics.friction import MassWithFriction
from hypa.physics.lifted import LiftedMatrices, lifted_matrices, matrix_powers, simulate_lifted, simulate_recursive
from hypa.physics.lti import LTIBlock, LTIModel, StateSpace, UnstablePhysicsError
from hypa.physics.mass_spring_damper import MassSpringDamper
from hypa.physics.normalized import NormalizedLTI, Scaling, default_state_std, normalize
from hypa.physics.parameters import ParameterSpec, PhysicalParameters
from hypa.physics.scan import affine_scan
from hypa.physics.scheduled import SchedulingError
from hypa.physics.systems import PHYSICS_SYSTEMS, build_system, resolve_system

__all__ = [
    "HOLDS",
    "PHYSICS_SYSTEMS",
    "DiscreteLTI",
    "FirstOrderLag",
    "LTIBlock",
    "LTIModel",
    "LiftedMatrices",
    "MassSpringDamper",
    "MassWithFriction",
    "NormalizedLTI",
    "ParameterSpec",
    "PhysicalParameters",
    "Scaling",
    "SchedulingError",
    "StateSpace",
    "SystemContractError",
    "UnstablePhysicsError",
    "affine_scan",
    "build_system",
    "check_system",
    "default_state_std",
    "discretize",
    "lifted_matrices",
    "matrix_powers",
    "normalize",
    "resolve_system",
    "simulate_lifted",
    "simulate_recursive",
]
