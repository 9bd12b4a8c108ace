"""Typed configuration of the simulated test bench (mirrored by conf/testbench/default.yaml).

Every effect the nominal linear single-track physics does not know is switchable
(``enabled``) and scalable, so a test can start from :meth:`TestbenchConfig.linear` (the
truth equals the linear physics) and hide exactly one effect on top of it.
All quantities are SI: angles in rad, angular rates in rad/s, times in s, lengths in m.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from omegaconf import DictConfig, OmegaConf

from hypa.core.errors import UserError, checked
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
        check(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any] | DictConfig | None = None) -> TestbenchConfig:
        """Defaults updated by a (partial, nested) dict; misspelled keys raise an error."""
        return cls().merged(data)

    @classmethod
    def from_hydra(cls, node: DictConfig | dict[str, Any] | None) -> TestbenchConfig:
        """The ``testbench`` node of a composed Hydra config: as :meth:`from_dict`, but it lists every
        record, so the records are exactly those it names (``~testbench.records.train_2`` drops one)."""
        if node is not None and not isinstance(node, (dict, DictConfig)):
            raise UserError(f"testbench is {type(node).__name__} {str(node)[:60]!r}, not a mapping of the test "
                            "bench's settings (conf/testbench/default.yaml)")
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


KEY = "testbench"  # the node of a command's configuration the settings are read from


def check(config: TestbenchConfig) -> None:
    """Every value of ``config`` of the right type and in its range, or a :class:`UserError` naming the
    setting (``testbench.sample_rate_hz=-5 must be > 0``): before anything is generated from it.

    The values that size the data (the sample rate, the records' and the manoeuvres' durations) are
    positive and finite, so that each record has a number of samples; whether those samples fit
    into this machine's memory is :func:`hypa.paper.testbench.memory.check_fits`. A value that the
    simulation divides by is positive (a zero would end it with a ZeroDivisionError), one that
    only shifts or scales is finite (an ``inf`` or ``nan`` would fill the files with NaN).
    """
    _finite(config, KEY)
    fs = checked(f"{KEY}.sample_rate_hz", config.sample_rate_hz, float, positive=True)
    if not config.records:
        raise UserError(f"{KEY}.records is empty: the test bench needs a record to generate (conf/testbench/"
                        "default.yaml lists train_1, train_2 and val)")
    tires, relax, load, rws = config.tires, config.relaxation, config.load_transfer, config.rear_steering
    for name, value in (("tires.mu", tires.mu), ("tires.shape_c", tires.shape_c),
                        ("relaxation.front_length_m", relax.front_length_m),
                        ("relaxation.rear_length_m", relax.rear_length_m),
                        ("load_transfer.track_front_m", load.track_front_m),
                        ("load_transfer.track_rear_m", load.track_rear_m),
                        ("load_transfer.roll_frequency_hz", load.roll_frequency_hz),
                        ("load_transfer.roll_damping", load.roll_damping),
                        ("load_transfer.stiffness_load_peak", load.stiffness_load_peak),
                        ("rear_steering.yaw_rate_ref", rws.yaw_rate_ref),
                        ("rear_steering.transient_tau_s", rws.transient_tau_s),
                        ("rear_steering.actuator_tau_s", rws.actuator_tau_s)):
        checked(f"{KEY}.{name}", value, float, positive=True)
    for name, value in (("load_transfer.cg_height_m", load.cg_height_m), ("rear_steering.rate_limit", rws.rate_limit),
                        ("rear_steering.angle_limit", rws.angle_limit), ("steering.delay_s", config.steering.delay_s),
                        ("steering.lag_tau_s", config.steering.lag_tau_s)):
        checked(f"{KEY}.{name}", value, float, minimum=0.0)
    if not tires.curvature_e < 1.0:
        raise UserError(f"{KEY}.tires.curvature_e={tires.curvature_e:g} must be < 1 (a monotonic rising branch)")
    checked(f"{KEY}.load_transfer.front_roll_share", load.front_roll_share, float, minimum=0.0)
    if not load.front_roll_share <= 1.0:
        raise UserError(f"{KEY}.load_transfer.front_roll_share={load.front_roll_share:g} must be between 0 and 1")
    if len(rws.table_speed_mps) != len(rws.table_ratio) or not rws.table_ratio:
        raise UserError(f"{KEY}.rear_steering.table_speed_mps and table_ratio need equal lengths (>= 1), not "
                        f"{len(rws.table_speed_mps)} and {len(rws.table_ratio)}")
    if any(b <= a for a, b in zip(rws.table_speed_mps, rws.table_speed_mps[1:])):
        raise UserError(f"{KEY}.rear_steering.table_speed_mps must be strictly increasing")
    _check_excitation(config.excitation)
    for name, record in config.records.items():
        _check_record(config, str(name), record, fs)


def _check_excitation(excitation: ExcitationConfig) -> None:
    """The steering robot's programmes: positive durations and frequencies, rests and ramps >= 0."""
    where = f"{KEY}.excitation"
    stochastic = excitation.stochastic
    checked(f"{where}.stochastic.amplitude", stochastic.amplitude, float, positive=True)
    checked(f"{where}.stochastic.crest_factor", stochastic.crest_factor, float, optional=True, positive=True)
    checked(f"{where}.stochastic.cutoff_hz", stochastic.cutoff_hz, float, positive=True)
    checked(f"{where}.stochastic.fade_s", stochastic.fade_s, float, minimum=0.0)
    for name in MANEUVERS:
        part = getattr(excitation, name)
        checked(f"{where}.{name}.duration_s", part.duration_s, float, positive=True)
        checked(f"{where}.{name}.lead_s", part.lead_s, float, minimum=0.0)
    checked(f"{where}.lane_change.change_s", excitation.lane_change.change_s, float, positive=True)
    checked(f"{where}.lane_change.hold_s", excitation.lane_change.hold_s, float, minimum=0.0)
    checked(f"{where}.step_steer.ramp_s", excitation.step_steer.ramp_s, float, minimum=0.0)
    checked(f"{where}.step_steer.hold_s", excitation.step_steer.hold_s, float, minimum=0.0)
    sweep = excitation.sine_sweep
    checked(f"{where}.sine_sweep.fade_s", sweep.fade_s, float, minimum=0.0)
    checked(f"{where}.sine_sweep.start_hz", sweep.start_hz, float, positive=True)
    checked(f"{where}.sine_sweep.end_hz", sweep.end_hz, float, positive=True)
    if sweep.end_hz == sweep.start_hz:
        raise UserError(f"{where}.sine_sweep.end_hz={sweep.end_hz:g} equals start_hz: a sweep needs two frequencies")


def _check_record(config: TestbenchConfig, name: str, record: RecordConfig, fs: float) -> None:
    """One record: a seed >= 0, known manoeuvres, a stochastic part with samples and a frequency below
    the cut-off (else the excitation is empty and the record NaN), a break frequency below the cut-off."""
    where = f"{KEY}.records.{name}"
    checked(f"{where}.seed", record.seed, int, minimum=0)
    unknown = [m for m in record.maneuvers if m not in MANEUVERS]
    if unknown:
        raise UserError(f"{where}.maneuvers: unknown maneuvers {', '.join(map(str, unknown))}; use "
                        f"{', '.join(MANEUVERS)}")
    duration = record.stochastic_duration_s
    if not isinstance(duration, bool) and isinstance(duration, (int, float)) and not duration > 0:
        raise UserError(f"record {name!r}: stochastic_duration_s must be > 0 (it is {duration:g}); give "
                        f"{where}.stochastic_duration_s=<seconds> or remove the record with ~{where}")
    duration = checked(f"{where}.stochastic_duration_s", duration, float, positive=True)
    cutoff = config.excitation.stochastic.cutoff_hz
    checked(f"{where}.break_frequency_hz", record.break_frequency_hz, float, positive=True)
    if not record.break_frequency_hz < cutoff:
        raise UserError(f"{where}.break_frequency_hz={record.break_frequency_hz:g} must be below "
                        f"{KEY}.excitation.stochastic.cutoff_hz={cutoff:g}")
    samples = round(duration * fs)
    if samples < 2 or fs / samples > cutoff:  # its lowest frequency fs / samples carries the power
        shortest = max(2.0 / fs, 1.0 / cutoff)
        raise UserError(f"{where}.stochastic_duration_s={duration:g} is too short at {KEY}.sample_rate_hz={fs:g}: "
                        f"the stochastic part needs 2 samples and a frequency below the cut-off "
                        f"({cutoff:g} Hz), so at least {shortest:.3g} s")


def _finite(node: Any, where: str) -> None:
    """Every number of the dataclass ``node`` (and of the ones inside it) finite: an ``inf`` or ``nan``
    fills the simulation with NaN. Ranges are checked by :func:`check`."""
    for f in dataclasses.fields(node):
        value, key = getattr(node, f.name), f"{where}.{f.name}"
        if dataclasses.is_dataclass(value):
            _finite(value, key)
        elif isinstance(value, dict):
            for name, item in value.items():
                if dataclasses.is_dataclass(item):
                    _finite(item, f"{key}.{name}")
        elif isinstance(value, (list, tuple)):
            if any(isinstance(v, float) and not math.isfinite(v) for v in value):
                raise UserError(f"{key}={list(value)} holds a number that is not finite")
        elif isinstance(value, float):
            checked(key, value, float)
