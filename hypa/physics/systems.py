"""Registered physical systems, by the name a model configuration uses.

Each entry builds the system for one block, given the block's name: systems with parameters
of their own (a lag's time constant) prefix them with it (``local_name``); the vehicle
systems read the shared vehicle parameters.
"""

from __future__ import annotations

from collections.abc import Callable

from hypa.physics.elements import FirstOrderLag
from hypa.physics.lti import LTIModel
from hypa.physics.mass_spring_damper import MassSpringDamper
from hypa.physics.vehicle import SingleTrack, SteeringGain

PHYSICS_SYSTEMS: dict[str, Callable[[str], LTIModel]] = {
    "single_track": lambda block: SingleTrack(rear_steering=True),  # u = [δf, δr]
    "single_track_front": lambda block: SingleTrack(rear_steering=False),  # u = [δf]
    "front_steering": lambda block: SteeringGain("front"),  # δsw -> δf = δsw / steering_ratio
    "rear_steering": lambda block: SteeringGain("rear"),  # δsw -> δr = rws_ratio δsw / steering_ratio
    "first_order_lag": FirstOrderLag,  # τ ẏ = u - y, parameter <block>/tau_s
    "mass_spring_damper": lambda block: MassSpringDamper(),
}


def build_system(name: str, block: str = "") -> LTIModel:
    """The system ``name`` for the block ``block`` (which prefixes the system's own parameters)."""
    if name not in PHYSICS_SYSTEMS:
        raise KeyError(f"unknown physics system {name!r}; known: {', '.join(PHYSICS_SYSTEMS)}")
    return PHYSICS_SYSTEMS[name](block)
