"""Registered physical systems, by the name a model configuration uses."""

from __future__ import annotations

from collections.abc import Callable

from hypa.physics.lti import LTIModel
from hypa.physics.mass_spring_damper import MassSpringDamper
from hypa.physics.vehicle import SingleTrack, SteeringGain

PHYSICS_SYSTEMS: dict[str, Callable[[], LTIModel]] = {
    "single_track": lambda: SingleTrack(rear_steering=True),  # u = [δf, δr]
    "single_track_front": lambda: SingleTrack(rear_steering=False),  # u = [δf]
    "front_steering": lambda: SteeringGain("front"),  # δsw -> δf = δsw / steering_ratio
    "rear_steering": lambda: SteeringGain("rear"),  # δsw -> δr = rws_ratio δsw / steering_ratio
    "mass_spring_damper": MassSpringDamper,
}


def build_system(name: str) -> LTIModel:
    if name not in PHYSICS_SYSTEMS:
        raise KeyError(f"unknown physics system {name!r}; known: {', '.join(PHYSICS_SYSTEMS)}")
    return PHYSICS_SYSTEMS[name]()
