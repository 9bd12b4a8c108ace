"""How the vehicle's channels are shown: SI radians are plotted and reported in degrees."""

import numpy as np

DEG = float(np.degrees(1.0))  # rad -> deg
DISPLAY_UNITS = {"yaw_rate": "deg/s", "side_slip": "deg", "rear_wheel_angle": "deg"}
