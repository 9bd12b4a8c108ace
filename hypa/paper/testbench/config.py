"""Typed configuration of the simulated test bench (mirrored by conf/testbench/default.yaml).

Every effect the nominal linear single-track physics does not know is switchable
(``enabled``) and scalable, so a test can start from :meth:`TestbenchConfig.linear` (the
truth equals the linear physics) and hide exactly one effect on top of it.
All quantities are SI: angles in rad, angular rates in rad/s, times in s, lengths in m.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from omegaconf import DictConfig, OmegaConf

from hypa.vehicle import VehicleParameters


@dataclass
class TireConfig:
    """Axle characteristics: Pacejka magic formula per axle, or linear ``Fy = c alpha``.

    ``Fy = D sin(C atan(B a - E (B a - atan(B a))))`` with ``D = mu Fz`` (static axle load
    ``Fz`` [N]) and ``B = c / (C D)``, so the slope at zero slip equals the cornering
    stiffness ``c`` [N/rad] of the truth vehicle.
    """

    enabled: bool = True  # false: linear axles, Fy = c alpha
    mu: float = 1.0  # [-] peak friction coefficient; larger values push saturation further out
    shape_c: float = 1.35  # [-] magic-formula shape factor C
    curvature_e: float = -0.5  # [-] magic-formula curvature factor E (< 1)


@dataclass
class RelaxationConfig:
    """First-order lag of each axle's slip angle, time constant ``sigma / v`` [s]."""

    enabled: bool = True
    front_length_m: float = 0.7  # [m] front axle relaxation length sigma_f
    rear_length_m: float = 0.6  # [m] rear axle relaxation length sigma_r


@dataclass
class LoadTransferConfig:
    """Lateral load transfer through the body's roll, and the tyres' load sensitivity.

    Cornering moves vertical load from the inner to the outer wheel of each axle:
    ``dFz = share m h a_roll / track`` (``share``: the axle's part of the roll stiffness,
    front ``front_roll_share``, rear the rest), where ``a_roll`` is the lateral acceleration
    through the body's roll mode (second order, ``roll_frequency_hz``, ``roll_damping``).
    Each wheel is a magic formula of its own load Fz (static ``Fz0`` = half the axle load):
    peak ``D = mu (1 + mu_load_gradient dfz) Fz`` with ``dfz = Fz / Fz0 - 1`` (MF pDy2) and
    cornering stiffness ``K(Fz) ~ sin(2 atan(Fz / (stiffness_load_peak Fz0)))`` (MF pKy2),
    scaled so the axle's slope at zero lateral acceleration is still ``c``. Both are
    degressive in load, so the axle loses stiffness and peak force as |a_y| grows: the
    outer wheel gains less than the inner one loses. Values of a mid-size sedan: centre of
    gravity 0.55 m high, 1.6 m tracks, 60 % of the roll stiffness at the front (understeer
    tuning), body roll at 1.5 Hz, 40 % damped; MF 5.2 tyre files of 205/60R15-sized tyres
    have pKy2 ~ 2 and pDy2 ~ -0.1 (Pacejka, Tire and Vehicle Dynamics, 3rd ed., App. 3).
    """

    enabled: bool = True  # false: both wheels of an axle carry half its static load
    cg_height_m: float = 0.55  # [m] centre-of-gravity height h
    track_front_m: float = 1.60  # [m]
    track_rear_m: float = 1.60  # [m]
    front_roll_share: float = 0.60  # [-] front axle's part of the roll stiffness
    roll_frequency_hz: float = 1.5  # [Hz] body roll natural frequency
    roll_damping: float = 0.4  # [-] body roll damping ratio
    stiffness_load_peak: float = 2.0  # [-] Fz / Fz0 at which a wheel's stiffness peaks (pKy2)
    mu_load_gradient: float = -0.1  # [-] relative change of mu per relative load change (pDy2)


@dataclass
class RearSteeringConfig:
    """Active rear-wheel-steering ECU, unknown to the physics.

    Command ``delta_r,cmd = strength (k(v) (1 + g tanh(|r| / r_ref)) delta_f,ECU + k_r r
    - k_t (delta_f,ECU - lowpass_tau_t(delta_f,ECU)))``: a speed-scheduled feedforward ratio
    ``k(v)`` (linear interpolation of the table, held constant beyond its ends) modulated by
    the yaw rate ``r`` (g < 0: less in-phase when turning hard, which offsets part of the
    tyres' growing understeer), a stabilizing yaw-rate feedback, and a phase-reversal term:
    right after a steering change the rear wheels steer against the front ones by ``k_t``
    (sharper yaw response), fading with ``tau_t`` into the in-phase ratio (stability); the
    control of Honda's and Nissan's four-wheel steering (Sano et al., SAE 860625; Irie and
    Kuroki, SAE 901748). In transfer-function form the linear part is
    ``k (1 + T_z s) / (1 + tau_t s)`` with ``T_z = (1 - k_t / k) tau_t`` < 0: a non-minimum-phase
    law no fixed ratio can follow. ``delta_f,ECU`` is the steering-wheel angle sensor over
    the steering ratio (the ECU does not see steering lag or dead time). The actuator
    follows the angle-limited command with a first-order lag whose rate is limited.
    """

    enabled: bool = True
    strength: float = 1.0  # [-] scales the whole command (0 = no rear steering)
    table_speed_mps: list[float] = field(
        default_factory=lambda: [0.0, 8.3, 16.7, 25.0, 33.3, 44.4, 55.6]
    )  # [m/s] breakpoints of the feedforward table
    table_ratio: list[float] = field(
        default_factory=lambda: [-0.20, -0.15, 0.0, 0.07, 0.12, 0.15, 0.16]
    )  # [-] rear / front wheel angle; < 0 counter-phase (low speed), > 0 in-phase
    yaw_rate_ratio_gain: float = -0.3  # [-] relative change g of the ratio at large |r|
    yaw_rate_ref: float = 0.15  # [rad/s] yaw rate r_ref at which 76 % of the change is reached
    yaw_rate_feedback_s: float = 0.005  # [rad/(rad/s)] = [s] feedback gain k_r
    transient_ratio: float = 0.3  # [-] k_t: counter-phase ratio right after a steering change
    transient_tau_s: float = 0.3  # [s] tau_t: time over which that counter-phase part fades
    actuator_tau_s: float = 0.07  # [s] first-order actuator time constant
    rate_limit: float = 0.175  # [rad/s] actuator rate limit (10 deg/s)
    angle_limit: float = 0.0524  # [rad] rear wheel angle limit (3 deg)


@dataclass
class SteeringConfig:
    """Path steering wheel -> front wheels: ``delta_f = delta_sw(t - delay) / i_s``, lagged."""

    delay_s: float = 0.0  # [s] input dead time (0 = off)
    lag_tau_s: float = 0.0  # [s] first-order steering lag time constant (0 = off)


@dataclass
class ChannelSensorConfig:
    """White measurement noise and a constant bias of one channel (channel units)."""

    noise_std: float = 0.0
    bias: float = 0.0


@dataclass
class SensorConfig:
    """Measurement errors per channel; ``noise_scale`` / ``bias_scale`` scale all channels."""

    enabled: bool = True
    noise_scale: float = 1.0  # [-]
    bias_scale: float = 1.0  # [-]
    steering_wheel_angle: ChannelSensorConfig = field(
        default_factory=lambda: ChannelSensorConfig(noise_std=0.0009)
    )  # [rad], 0.05 deg
    yaw_rate: ChannelSensorConfig = field(
        default_factory=lambda: ChannelSensorConfig(noise_std=0.0026, bias=0.0017)
    )  # [rad/s], 0.15 deg/s noise, 0.1 deg/s gyro bias
    side_slip: ChannelSensorConfig = field(
        default_factory=lambda: ChannelSensorConfig(noise_std=0.0009, bias=0.00035)
    )  # [rad], 0.05 deg noise, 0.02 deg optical sensor misalignment
    lateral_acceleration: ChannelSensorConfig = field(
        default_factory=lambda: ChannelSensorConfig(noise_std=0.05, bias=0.03)
    )  # [m/s^2], mounting tilt lets gravity leak in
    velocity: ChannelSensorConfig = field(
        default_factory=lambda: ChannelSensorConfig(noise_std=0.02)
    )  # [m/s]
    rear_wheel_angle: ChannelSensorConfig = field(
        default_factory=lambda: ChannelSensorConfig(noise_std=0.0001)
    )  # [rad], 0.006 deg


@dataclass
class StochasticConfig:
    """Steering-wheel angle with a flat PSD up to the record's break frequency, 1/f^2 above.

    The power is zero above ``cutoff_hz``; the realization is scaled so that its peak
    ``|delta_sw|`` equals ``amplitude`` and faded in and out with raised-cosine ramps.
    ``crest_factor`` (peak / RMS) makes the robot use its angle range: the Gaussian
    realization is scaled to RMS = amplitude / crest_factor, then clipped and band-limited
    again a few times; ``None`` keeps the plain Gaussian (peak / RMS ~ 3.5-4).
    """

    amplitude: float = 0.611  # [rad] peak steering-wheel angle delta_sw,max (35 deg)
    crest_factor: float | None = 2.3  # [-] target peak / RMS, None = plain Gaussian
    cutoff_hz: float = 5.0  # [Hz] no power above
    fade_s: float = 2.0  # [s] raised-cosine fade-in / fade-out at the record ends


@dataclass
class LaneChangeConfig:
    """ISO-3888-like double lane change: out and back, each a full sine of steering."""

    duration_s: float = 15.0  # [s] segment length, rest before and after included
    amplitude: float = 0.436  # [rad] steering-wheel amplitude (25 deg)
    change_s: float = 2.5  # [s] duration of one lane change (one full sine period)
    hold_s: float = 1.0  # [s] straight driving in the offset lane
    lead_s: float = 2.0  # [s] rest before the manoeuvre


@dataclass
class StepSteerConfig:
    """Ramped step steer to the left, held, ramped back (ISO-7401-like)."""

    duration_s: float = 15.0  # [s] segment length
    amplitude: float = 0.349  # [rad] steering-wheel step height (20 deg)
    ramp_s: float = 0.15  # [s] raised-cosine ramp (about 200 deg/s at 20 deg)
    hold_s: float = 5.0  # [s] time at the step height
    lead_s: float = 2.0  # [s] rest before the step


@dataclass
class SineSweepConfig:
    """Constant-amplitude logarithmic sine sweep of the steering-wheel angle."""

    duration_s: float = 30.0  # [s] segment length
    amplitude: float = 0.175  # [rad] steering-wheel amplitude (10 deg)
    start_hz: float = 0.2  # [Hz]
    end_hz: float = 4.0  # [Hz]
    lead_s: float = 1.0  # [s] rest before and after the sweep
    fade_s: float = 1.0  # [s] raised-cosine amplitude fade-in / fade-out


@dataclass
class ExcitationConfig:
    """Steering-robot programme: the stochastic signal and the deterministic manoeuvres."""

    stochastic: StochasticConfig = field(default_factory=StochasticConfig)
    lane_change: LaneChangeConfig = field(default_factory=LaneChangeConfig)
    step_steer: StepSteerConfig = field(default_factory=StepSteerConfig)
    sine_sweep: SineSweepConfig = field(default_factory=SineSweepConfig)


MANEUVERS = ("lane_change", "step_steer", "sine_sweep")


@dataclass
class RecordConfig:
    """One measured-data file: a stochastic part, then the listed manoeuvres in order."""

    seed: int = 0  # seeds the excitation and the sensor noise
    stochastic_duration_s: float = 300.0  # [s]
    break_frequency_hz: float = 1.0  # [Hz] end of the flat part of the excitation PSD
    maneuvers: list[str] = field(default_factory=list)  # names from MANEUVERS


def _default_records() -> dict[str, RecordConfig]:
    return {
        "train_1": RecordConfig(seed=1, stochastic_duration_s=300.0, break_frequency_hz=1.0),
        "train_2": RecordConfig(seed=2, stochastic_duration_s=300.0, break_frequency_hz=1.0),
        "val": RecordConfig(
            seed=3,
            stochastic_duration_s=120.0,
            break_frequency_hz=0.8,
            maneuvers=list(MANEUVERS),
        ),
    }


@dataclass
class TestbenchConfig:
    """Everything that determines the generated files (the cache key hashes all of it)."""

    __test__ = False  # not a pytest test class despite the name

    sample_rate_hz: float = 1024.0  # [Hz] integration and file sample rate
    vehicle: VehicleParameters = field(default_factory=VehicleParameters)  # truth vehicle
    tires: TireConfig = field(default_factory=TireConfig)
    relaxation: RelaxationConfig = field(default_factory=RelaxationConfig)
    load_transfer: LoadTransferConfig = field(default_factory=LoadTransferConfig)
    rear_steering: RearSteeringConfig = field(default_factory=RearSteeringConfig)
    steering: SteeringConfig = field(default_factory=SteeringConfig)
    sensors: SensorConfig = field(default_factory=SensorConfig)
    excitation: ExcitationConfig = field(default_factory=ExcitationConfig)
    records: dict[str, RecordConfig] = field(default_factory=_default_records)

    def __post_init__(self) -> None:
        rws = self.rear_steering
        if len(rws.table_speed_mps) != len(rws.table_ratio) or len(rws.table_ratio) < 1:
            raise ValueError("rear_steering.table_speed_mps and table_ratio need equal lengths")
        if any(b <= a for a, b in zip(rws.table_speed_mps, rws.table_speed_mps[1:])):
            raise ValueError("rear_steering.table_speed_mps must be strictly increasing")
        if not self.tires.curvature_e < 1.0:
            raise ValueError("tires.curvature_e must be < 1 for a monotonic rising branch")
        load = self.load_transfer
        if not (0.0 <= load.front_roll_share <= 1.0 and load.roll_frequency_hz > 0
                and load.roll_damping > 0 and load.stiffness_load_peak > 0):
            raise ValueError("load_transfer: need 0 <= front_roll_share <= 1 and positive "
                             "roll_frequency_hz, roll_damping, stiffness_load_peak")
        if self.steering.delay_s < 0 or self.steering.lag_tau_s < 0:
            raise ValueError("steering.delay_s and steering.lag_tau_s must be >= 0")
        for name, record in self.records.items():
            unknown = [m for m in record.maneuvers if m not in MANEUVERS]
            if unknown:
                raise ValueError(f"record {name!r}: unknown maneuvers {unknown}, use {MANEUVERS}")
            if not record.stochastic_duration_s > 0:
                raise ValueError(f"record {name!r}: stochastic_duration_s must be > 0 (it is "
                                 f"{record.stochastic_duration_s:g}); remove a record with ~testbench.records.{name}")
            if not 0 < record.break_frequency_hz < self.excitation.stochastic.cutoff_hz:
                raise ValueError(f"record {name!r}: need 0 < break_frequency_hz < cutoff_hz")

    @classmethod
    def from_dict(cls, data: dict[str, Any] | DictConfig | None = None) -> TestbenchConfig:
        """Defaults updated by a (partial, nested) dict; misspelled keys raise an error."""
        return cls().merged(data)

    @classmethod
    def from_hydra(cls, node: DictConfig | dict[str, Any] | None) -> TestbenchConfig:
        """The ``testbench`` node of a composed Hydra config: as :meth:`from_dict`, but it lists every
        record, so the records are exactly those it names (``~testbench.records.train_2`` drops one)."""
        config = cls.from_dict(node)
        named = (node or {}).get("records")
        if named is None:
            return config
        return dataclasses.replace(config, records={k: v for k, v in config.records.items() if k in named})

    @classmethod
    def linear(cls, noise: bool = False) -> TestbenchConfig:
        """Clean data: the truth equals the linear single-track model of ``vehicle``.

        Linear axles, no relaxation, no rear-wheel steering, no steering lag or dead time,
        no sensor bias; white sensor noise only if ``noise``.
        """
        return cls().merged(
            {
                "tires": {"enabled": False},
                "relaxation": {"enabled": False},
                "load_transfer": {"enabled": False},
                "rear_steering": {"enabled": False},
                "steering": {"delay_s": 0.0, "lag_tau_s": 0.0},
                "sensors": {"enabled": noise, "bias_scale": 0.0},
            }
        )

    def merged(self, overrides: dict[str, Any] | DictConfig | None) -> TestbenchConfig:
        """A copy with ``overrides`` (partial nested dict or OmegaConf node) applied."""
        schema = OmegaConf.structured(self)
        # VehicleParameters is frozen, which OmegaConf turns into a read-only node.
        OmegaConf.set_readonly(schema.vehicle, False)
        merged = OmegaConf.merge(schema, overrides or {})
        return OmegaConf.to_object(merged)  # type: ignore[return-value]

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict (JSON-serializable), the inverse of :meth:`from_dict`."""
        return dataclasses.asdict(self)
