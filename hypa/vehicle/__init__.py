"""The vehicle: the paper's instance of hypa's generic core.

Its physics (the linear single track with front and rear steering, the steering gains and the
vehicle's named parameters) lives here; ``SYSTEMS`` registers them as built-in systems of model
YAMLs (``system: single_track``), the core knows them only through that registry.
"""

from collections.abc import Callable

from hypa.physics.lti import LTIModel
from hypa.vehicle.physics import SingleTrack, SteeringGain, VehicleParameters, parameter_spec, vehicle_parameters

SYSTEMS: dict[str, Callable[[str], LTIModel]] = {
    "single_track": lambda block: SingleTrack(rear_steering=True),  # u = [δf, δr]
    "single_track_front": lambda block: SingleTrack(rear_steering=False),  # u = [δf]
    "front_steering": lambda block: SteeringGain("front"),  # δsw -> δf = δsw / steering_ratio
    "rear_steering": lambda block: SteeringGain("rear"),  # δsw -> δr = rws_ratio δsw / steering_ratio
}

__all__ = ["SYSTEMS", "SingleTrack", "SteeringGain", "VehicleParameters", "parameter_spec", "vehicle_parameters"]
