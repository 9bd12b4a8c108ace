"""The paper's vehicle instance: linear single-track model and its steering blocks.

Their parameters' nominal values are the default ``VehicleParameters``; a model takes the
values of the ``vehicle`` config instead (``LTIModel.parameter_specs``).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, fields

import torch
from torch import Tensor

from hypa.physics.lti import LTIModel, StateSpace
from hypa.physics.parameters import ParameterSpec, PhysicalParameters


@dataclass(frozen=True)
class VehicleParameters:
    """Named physical parameters of the single-track model (SI units).

    mass [kg], izz [kg m^2], lf / lr [m] (centre of gravity to front / rear axle),
    cf / cr [N/rad] (axle cornering stiffness), steering_ratio [-] (steering-wheel angle /
    front wheel angle), velocity [m/s], rws_ratio [-] (rear / front wheel angle of a
    fixed-ratio rear-wheel steering).
    """

    mass: float = 1900.0
    izz: float = 3300.0
    lf: float = 1.42
    lr: float = 1.53
    cf: float = 150000.0
    cr: float = 200000.0
    steering_ratio: float = 15.0
    velocity: float = 33.3
    rws_ratio: float = 0.1

    def __post_init__(self) -> None:
        for name in ("mass", "izz", "lf", "lr", "cf", "cr", "steering_ratio", "velocity"):
            value = getattr(self, name)
            if not value > 0:
                raise ValueError(f"vehicle parameter {name!r} must be positive, got {value}")

    @property
    def wheelbase(self) -> float:
        """lf + lr [m]."""
        return self.lf + self.lr

    def as_dict(self) -> dict[str, float]:
        return asdict(self)

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))


_UNITS = {"mass": "kg", "izz": "kg m^2", "lf": "m", "lr": "m", "cf": "N/rad", "cr": "N/rad",
          "steering_ratio": "-", "velocity": "m/s", "rws_ratio": "-"}


def parameter_spec(name: str, value: float, trainable: bool = False) -> ParameterSpec:
    """Spec of a vehicle parameter; all but ``rws_ratio`` (a signed ratio) stay positive."""
    if name not in _UNITS:
        raise KeyError(f"unknown vehicle parameter {name!r}; known: {', '.join(_UNITS)}")
    return ParameterSpec(name, float(value), _UNITS[name], positive=name != "rws_ratio", trainable=trainable)


def _specs(names: tuple[str, ...]) -> tuple[ParameterSpec, ...]:
    """Specs of ``names`` at the default vehicle's values (the ``vehicle`` config overrides them)."""
    nominal = VehicleParameters()
    return tuple(parameter_spec(k, getattr(nominal, k)) for k in names)


def vehicle_parameters(values: VehicleParameters, trainable: Iterable[str] = ()) -> PhysicalParameters:
    """All vehicle parameters as a ``PhysicalParameters`` module; ``trainable`` names are learned."""
    trainable = set(trainable)
    unknown = trainable - set(_UNITS)
    if unknown:
        raise KeyError(f"unknown vehicle parameters {sorted(unknown)}; known: {', '.join(_UNITS)}")
    return PhysicalParameters(parameter_spec(k, v, k in trainable) for k, v in values.as_dict().items())


class SingleTrack(LTIModel):
    """Linear single-track (bicycle) model at constant speed, as printed in the paper.

    States x = [yaw_rate ψ̇ (rad/s), side_slip β (rad)], inputs u = [front_wheel_angle δf,
    rear_wheel_angle δr] (rad), or δf alone for the front-steering-only variant:

        A = [[-(cf lf² + cr lr²)/(v Izz),   -(cf lf - cr lr)/Izz      ],
             [-1 - (cf lf - cr lr)/(v² m),  -(cf + cr)/(v m)          ]]
        B = [[ cf lf/Izz,   -cr lr/Izz ],
             [ cf/(v m),     cr/(v m)  ]]
    """

    state_names = ("yaw_rate", "side_slip")
    output_names = ("yaw_rate", "side_slip")
    parameters = _specs(("mass", "izz", "lf", "lr", "cf", "cr", "velocity"))

    def __init__(self, rear_steering: bool = True) -> None:
        self.rear_steering = rear_steering
        self.input_names = ("front_wheel_angle", "rear_wheel_angle") if rear_steering else ("front_wheel_angle",)

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        """The printed A, B, vectorized over the two axles k (few ops: rebuilt every step).

        The axle's lateral force is c_k (δ_k - α_k) with slip angle α_k = β + l_k ψ̇ / v
        (signed lever arms l = [lf, -lr]); it turns the car through l_k / Izz and bends its path
        through 1 / (v m). So B = diag(1/Izz, 1/(v m)) [[c_k l_k], [c_k]] and, because the
        forces from the states are -B α, A = -B [l / v, 1] - [[0, 0], [1, 0]]: its ψ̇ column is
        -(B l + [0, v]) / v, its β column -B 1. Batch-safe (``scheduled.batch_layout``): with
        each parameter a (K,) tensor the same code gives A, B (2, 2, K), so a scheduled
        velocity costs one call, not a vmap.
        """
        m, izz, lf, lr, cf, cr, v = (p[k] for k in ("mass", "izz", "lf", "lr", "cf", "cr", "velocity"))
        stiffness, arm = torch.stack([cf, cr]), torch.stack([lf, -lr])  # (2,) per axle
        b = torch.stack([stiffness * arm, stiffness]) / torch.stack([izz, v * m])[:, None]  # (2, 2): rows yaw, lateral
        turn = (b * arm).sum(1) + torch.stack([torch.zeros_like(v), v])  # B l + [0, v]
        a = -torch.stack([turn / v, b.sum(1)], 1)
        eye = torch.eye(2, dtype=a.dtype, device=a.device)
        return StateSpace(a, b if self.rear_steering else b[:, :1], eye, a.new_zeros(2, 1 + self.rear_steering))


class SingleTrackRelaxation(SingleTrack):
    """The linear single track whose axle forces lag the slip: tire relaxation.

    A tire builds its lateral force over a rolling distance, the relaxation length σ [m]
    (0.3-1 m for car tires), so each axle's effective slip s_k follows its kinematic slip with
    the speed-dependent time constant σ / v:

        σ / v · ṡ_k + s_k = δ_k - β - l_k ψ̇ / v,    F_k = c_k s_k

    States x = [yaw_rate, side_slip, front_slip, rear_slip] (rad/s, rad, rad, rad); outputs
    yaw rate and side slip. As σ → 0 it is the single track (``SingleTrack``), exactly.
    """

    state_names = ("yaw_rate", "side_slip", "front_slip", "rear_slip")
    output_names = ("yaw_rate", "side_slip")
    parameters = (*SingleTrack.parameters, ParameterSpec("relaxation_length", 0.3, "m"))

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        m, izz, lf, lr, cf, cr, v, sigma = (p[k] for k in ("mass", "izz", "lf", "lr", "cf", "cr", "velocity",
                                                             "relaxation_length"))
        z = torch.zeros_like(m)
        one = torch.ones_like(m)
        rate = v / sigma  # 1 / relaxation time
        a = torch.stack([
            torch.stack([z, z, cf * lf / izz, -cr * lr / izz]),
            torch.stack([-one, z, cf / (v * m), cr / (v * m)]),
            torch.stack([-rate * lf / v, -rate, -rate, z]),
            torch.stack([rate * lr / v, -rate, z, -rate]),
        ])
        b = torch.stack([torch.stack([z, z]), torch.stack([z, z]), torch.stack([rate, z]), torch.stack([z, rate])])
        c = torch.stack([torch.stack([one, z, z, z]), torch.stack([z, one, z, z])])
        inputs = 2 if self.rear_steering else 1
        return StateSpace(a, b[:, :inputs], c, m.new_zeros(2, inputs))


GRAVITY = 9.81  # [m/s^2]
SHAPE_C, CURVATURE_E = 1.35, -0.5  # the magic formula's shape and curvature of a passenger-car axle


class SingleTrackSaturation(SingleTrack):
    """The single track with saturating axles: nonlinear physics in Lur'e form.

    Each axle's lateral force follows Pacejka's magic formula of its slip α_k = δ_k - β - l_k ψ̇ / v,

        F_k(α) = D_k sin(C atan(B_k α - E (B_k α - atan(B_k α)))),   D_k = μ F_z,k,   B_k = c_k / (C D_k)

    with the static axle loads F_z,f = m g lr / (lf + lr), F_z,r = m g lf / (lf + lr), so its
    slope at zero slip is the cornering stiffness c_k and it saturates at μ F_z,k. The linear
    single track is ``matrices``; the force deficit w_k = F_k(α_k) - c_k α_k enters through
    F = diag(1/Izz, 1/(m v)) [[lf, -lr], [1, 1]]. As μ → ∞ it is the single track.
    """

    parameters = (*SingleTrack.parameters, ParameterSpec("mu", 1.0, "-"))

    def feedback(self, p: Mapping[str, Tensor]) -> Tensor:
        m, izz, lf, lr, v = (p[k] for k in ("mass", "izz", "lf", "lr", "velocity"))
        arm = torch.stack([lf, -lr])
        return torch.stack([arm / izz, torch.ones_like(arm) / (v * m)])

    def prepare(self, p: Mapping[str, Tensor]) -> Mapping[str, Tensor]:
        return {**p, **axle_constants(p)}

    def nonlinearity(self, x: Tensor, u: Tensor, p: Mapping[str, Tensor]) -> Tensor:
        # slip α = [δf, δr] - x @ kinematics: kinematics (2, 2) maps (ψ̇, β) to the axles' slip
        slip = -(x[..., :2] @ p["kinematics"])
        slip = slip + (u[..., :2] if self.rear_steering else torch.nn.functional.pad(u[..., :1], (0, 1)))
        return force_deficit(slip, p)


def axle_constants(p: Mapping[str, Tensor]) -> dict[str, Tensor]:
    """What the axle forces need from the parameters only: stiffnesses c_k, peaks D_k = μ F_z,k,
    the magic formula's B_k, and the map from (ψ̇, β) to the slips."""
    m, lf, lr, cf, cr, mu, v = (p[k] for k in ("mass", "lf", "lr", "cf", "cr", "mu", "velocity"))
    stiffness = torch.stack([cf, cr])
    peak = mu * m * GRAVITY * torch.stack([lr, lf]) / (lf + lr)  # D_k
    kinematics = torch.stack([torch.stack([lf / v, -lr / v]), torch.ones(2, dtype=m.dtype, device=m.device)])
    return {"stiffness": stiffness, "peak": peak, "shape_b": stiffness / (SHAPE_C * peak), "kinematics": kinematics}


def force_deficit(slip: Tensor, p: Mapping[str, Tensor]) -> Tensor:
    """F_k(α_k) - c_k α_k (..., 2) of the magic-formula axles at slips α (..., 2) [rad];
    ``p`` holds ``axle_constants``."""
    bx = p["shape_b"] * slip
    force = p["peak"] * torch.sin(SHAPE_C * torch.atan(bx - CURVATURE_E * (bx - torch.atan(bx))))
    return force - p["stiffness"] * slip


class SingleTrackRelaxationSaturation(SingleTrackRelaxation):
    """Tire relaxation and saturating axles together: the relaxed slip states s_k drive the
    magic-formula forces F_k(s_k) (``SingleTrackSaturation``'s), the deficit entering yaw and
    side slip through F = [[lf/Izz, -lr/Izz], [1/(m v), 1/(m v)], [0, 0], [0, 0]]."""

    parameters = (*SingleTrackRelaxation.parameters, ParameterSpec("mu", 1.0, "-"))

    def feedback(self, p: Mapping[str, Tensor]) -> Tensor:
        upper = SingleTrackSaturation.feedback(self, p)
        return torch.cat([upper, upper.new_zeros(2, 2)])

    def prepare(self, p: Mapping[str, Tensor]) -> Mapping[str, Tensor]:
        return {**p, **axle_constants(p)}

    def nonlinearity(self, x: Tensor, u: Tensor, p: Mapping[str, Tensor]) -> Tensor:
        return force_deficit(x[..., 2:4], p)


class SteeringGain(LTIModel):
    """A static steering transmission: no states, y = D u.

    ``front``: δf = δsw / steering_ratio (a fixed-ratio mechanical steering).
    ``rear``:  δr = rws_ratio · δsw / steering_ratio (a fixed-ratio rear steering, for V3).
    """

    state_names: tuple[str, ...] = ()
    input_names = ("steering_wheel_angle",)

    def __init__(self, axle: str = "front") -> None:
        if axle not in ("front", "rear"):
            raise ValueError(f"axle must be 'front' or 'rear', got {axle!r}")
        self.axle = axle
        self.output_names = (f"{axle}_wheel_angle",)
        self.parameters = _specs(("steering_ratio",) if axle == "front" else ("steering_ratio", "rws_ratio"))

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        ratio = p["steering_ratio"]
        gain = 1.0 / ratio if self.axle == "front" else p["rws_ratio"] / ratio
        empty = ratio.new_zeros(0, 0)
        return StateSpace(empty, ratio.new_zeros(0, 1), ratio.new_zeros(1, 0), gain.reshape(1, 1))


class SideSlipAtSensor(LTIModel):
    """The side slip where it is measured: a point ``sensor_x`` [m] ahead of the centre of gravity.

    A rigid body turning at ψ̇ moves a point x ahead of its centre of gravity sideways at
    v_y + x ψ̇, so its slip angle there is (small angles)

        β_s = β + x ψ̇ / v,    y = D u with u = [ψ̇, β], D = [[x / v, 1]]

    A side slip from a localization's v_y (GNSS antenna, IMU) is taken at that point, not at the
    centre of gravity the single track describes. On a course driven mostly one way round, the
    mean of x ψ̇ / v reads as a side-slip offset; a single track fitted without it can run a
    cornering stiffness to infinity to make β small where the sensor is. No states; ``velocity``
    (the vehicle's, or scheduled like the single track's) sets the lever arm's angle.
    """

    state_names: tuple[str, ...] = ()
    input_names = ("yaw_rate", "side_slip")
    output_names = ("side_slip",)
    parameters = (ParameterSpec("sensor_x", 0.0, "m", positive=False), *_specs(("velocity",)))

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        x, v = p["sensor_x"], p["velocity"]
        arm = torch.stack([torch.stack([x / v, torch.ones_like(v)])])  # (1, 2): batch-safe (trailing samples)
        return StateSpace(v.new_zeros(0, 0), v.new_zeros(0, 2), v.new_zeros(1, 0), arm)
