"""The vehicle: the paper's instance of hypa's generic core.

Its physics (the single track with front and rear steering, linear or with tire relaxation
and saturating axles, the steering gains and the vehicle's named parameters) lives here, with
its catalogue of causes for the diagnosis (``CATALOGUE``); ``SYSTEMS`` registers them as built-in systems of model
YAMLs (``system: single_track``), the core knows them only through that registry.
"""

from collections.abc import Callable
from pathlib import Path

from hypa.physics.lti import LTIModel
from hypa.vehicle.physics import (
                                  SideSlipAtSensor,
                                  SingleTrack,
                                  SingleTrackRelaxation,
                                  SingleTrackRelaxationSaturation,
                                  SingleTrackSaturation,
                                  SteeringGain,
                                  VehicleParameters,
                                  parameter_spec,
                                  vehicle_parameters,
)

SYSTEMS: dict[str, Callable[[str], LTIModel]] = {
    "single_track": lambda block: SingleTrack(rear_steering=True),  # u = [δf, δr]
    "single_track_front": lambda block: SingleTrack(rear_steering=False),  # u = [δf]
    "front_steering": lambda block: SteeringGain("front"),  # δsw -> δf = δsw / steering_ratio
    "rear_steering": lambda block: SteeringGain("rear"),  # δsw -> δr = rws_ratio δsw / steering_ratio
    # with tire relaxation (axle forces lag the slip over relaxation_length [m]): 4 states
    "single_track_relaxation": lambda block: SingleTrackRelaxation(rear_steering=True),
    "single_track_front_relaxation": lambda block: SingleTrackRelaxation(rear_steering=False),
    # with saturating axles (magic formula, peak friction mu): nonlinear, simulated step by step
    "single_track_saturation": lambda block: SingleTrackSaturation(rear_steering=True),
    "single_track_front_saturation": lambda block: SingleTrackSaturation(rear_steering=False),
    "single_track_relaxation_saturation": lambda block: SingleTrackRelaxationSaturation(rear_steering=True),
    "single_track_front_relaxation_saturation": lambda block: SingleTrackRelaxationSaturation(rear_steering=False),
    # the side slip at a sensor sensor_x [m] ahead of the centre of gravity: [yaw_rate, side_slip] -> side_slip
    "side_slip_at_sensor": lambda block: SideSlipAtSensor(),
}

CATALOGUE = Path(__file__).with_name("catalogue.yaml")  # the vehicle's causes for hypa diagnose model=M

__all__ = ["CATALOGUE", "SYSTEMS", "SideSlipAtSensor", "SingleTrack", "SingleTrackRelaxation",
           "SingleTrackRelaxationSaturation", "SingleTrackSaturation", "SteeringGain", "VehicleParameters",
           "parameter_spec", "vehicle_parameters"]
