"""A Wiener–Hammerstein circuit: a linear filter, a static nonlinearity, a second linear filter.

    u ─ G1 ─ z ─ f(z) ─ v ─ G2 ─ y

Each filter has unit static gain; the nonlinearity carries the gain. ``f`` is a **knee**: linear
with slope ``slope`` below the knee, the slope changing by ``slope_change`` above it, as a diode
conducts through a series resistance (a clipper; Shockley's law with an ohmic resistance, written
with the Lambert W function):

    f(z) = slope z + slope_change w W(exp((z - knee) / w)),        w = knee_width

The diode's part, q = w W(e^((z - knee)/w)), solves q + w ln(q / w) = z - knee: it grows as
w e^((z - knee)/w) below the knee (the diode's exponential onset, w its thermal voltage times its
ideality, in the circuit's unit) and as z - knee - w ln((z - knee)/w) above it (the resistance: its
slope approaches 1 as w / (z - knee), slower than exponentially). So f'(z) goes from ``slope`` to
``slope + slope_change`` (``slope_change`` = -``slope``: a clamp; 0: a linear circuit). On the
benchmark's circuit, identified from the first 20 000 samples of its estimation record (under a
first-order hold), this shape leaves 0.571 mV of test error where a logistic slope (a softplus, the
same four parameters) leaves 0.728 mV.

- G1 = ω1² / (s² + 2ζ1ω1 s + ω1²) · a1 / (s + a1): a resonance (``first_frequency_hz``,
  ``first_damping``) and a real pole (``first_pole_hz``).
- G2 = ω2² (s²/ωz² + 2ζz s/ωz + 1) / (s² + 2ζ2ω2 s + ω2²) · a2 / (s + a2): a resonance
  (``second_frequency_hz``, ``second_damping``), a pair of zeros (``notch_frequency_hz``,
  ``notch_damping``: a notch where ζz is near 0, signed: negative puts the zeros in the right
  half-plane) and a real pole (``second_pole_hz``).
- ``output_offset``: a constant added to y (the output stage's offset, in the signals' unit; 0 by
  default). It enters as a constant a2 · offset in ẏ: y's state is the output with its offset,
  exactly (nothing reads y back). On the benchmark's circuit the physics' free run has a mean error
  of 0.15 mV on every part of the record.

All six states are in the input's unit: G1's low-passed input q1 and its rate q2 = q̇1/ω1, z;
G2's low-passed v r1 and r2 = ṙ1/ω2, y. Written in Lur'e form (ẋ = A x + B u + F w, w the
knee's term), the knee is the only nonlinear part: the linear filters run exactly under the
model's hold and the knee's output is held linear over a sample (``hypa.physics.lure``). The
benchmark's circuit (``../shared/data/wiener_hammerstein``) is driven by a smooth signal: its
model (``wiener_hammerstein_grey``) sets ``hold: cubic``.

Parameters are the block's own (``<block>/first_frequency_hz``, ...), so several such circuits can
share a model; the class's nominal values are placeholders a model sets. The knee and its width are
in the signals' unit (``unit``, V: a circuit's; a model may give them in mV).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch
from torch import Tensor

from hypa.physics.elements import local_name
from hypa.physics.parameters import ParameterSpec
from hypa.physics.statespace import LTIModel, StateSpace

TWO_PI = 2.0 * math.pi


def knee(z: Tensor, slope_change: Tensor, at: Tensor, width: Tensor) -> Tensor:
    """The knee's nonlinear term d w W(e^((z - at) / w)) (module docstring): a diode's current through
    its series resistance, 0 well below ``at`` (exponentially), d (z - at) well above (as w / (z - at))."""
    return slope_change * width * lambert_w_exp((z - at) / width)


def lambert_w_exp(s: Tensor, iterations: int = 3) -> Tensor:
    """W(e^s), the Lambert W function of e^s, for any s without overflow: L = ln W solves e^L + L = s
    (Newton's method on a convex increasing function: from L0 = min(s, ln max(s, 1)), ``iterations``
    steps and a last one reach 4e-15 relative over s in [-60, 60]), the last step taken with the graph,
    so the derivative is W / (1 + W) per unit s (to 1e-7)."""
    with torch.no_grad():
        level = torch.minimum(s, torch.log(s.clamp_min(1.0)))
        for _ in range(iterations):
            grown = level.exp()
            level = level - (grown + level - s) / (grown + 1.0)
    grown = level.exp()
    return (level - (grown + level - s) / (grown + 1.0)).exp()


class WienerHammerstein(LTIModel):
    """u -> G1 -> knee -> G2 -> y (module docstring): six states, thirteen parameters."""

    state_names = ("first_filtered", "first_rate", "first_out", "second_filtered", "second_rate", "output")
    input_names = ("input",)
    output_names = ("output",)
    NAMES = (
        ("first_frequency_hz", 1.0, "Hz", True),  # G1's resonance
        ("first_damping", 0.7, "-", True),
        ("first_pole_hz", 1.0, "Hz", True),  # G1's real pole
        ("slope", 1.0, "-", False),  # f'(z) below the knee (the circuit's gain there)
        ("slope_change", 0.0, "-", False),  # f'(z) above the knee minus below it
        ("knee", 1.0, "signal", False),  # where the slope changes [the signals' unit]
        ("knee_width", 0.1, "signal", True),  # over how much of z it changes [the signals' unit]
        ("second_frequency_hz", 1.0, "Hz", True),  # G2's resonance
        ("second_damping", 0.7, "-", True),
        ("second_pole_hz", 1.0, "Hz", True),  # G2's real pole
        ("notch_frequency_hz", 10.0, "Hz", True),  # G2's pair of zeros
        ("notch_damping", 1.0, "-", False),  # signed: < 0 right half-plane zeros
        ("output_offset", 0.0, "signal", False),  # added to y [the signals' unit]
    )

    def __init__(self, prefix: str = "", unit: str = "V") -> None:
        """``unit``: the input's (and every state's, the knee's): a circuit's volts unless said."""
        self.parameters = tuple(ParameterSpec(local_name(prefix, name), value, unit if kind == "signal" else kind,
                                              positive=positive)
                                for name, value, kind, positive in self.NAMES)
        self._names = {name: spec.name for (name, *_), spec in zip(self.NAMES, self.parameters, strict=True)}

    def _values(self, p: Mapping[str, Tensor]) -> dict[str, Tensor]:
        return {name: p[full] for name, full in self._names.items()}

    def matrices(self, p: Mapping[str, Tensor]) -> StateSpace:
        v = self._values(p)
        w1, z1, a1 = TWO_PI * v["first_frequency_hz"], v["first_damping"], TWO_PI * v["first_pole_hz"]
        w2, z2, a2 = TWO_PI * v["second_frequency_hz"], v["second_damping"], TWO_PI * v["second_pole_hz"]
        wz, zz, slope = TWO_PI * v["notch_frequency_hz"], v["notch_damping"], v["slope"]
        o = torch.zeros_like(w1)
        k = w2 * w2 / (wz * wz)  # r̈1's weight in G2's numerator, s²/ωz²
        # ẏ = a2 (n - y), n = (r̈1 + 2ζz ωz ṙ1 + ωz² r1) / ωz², r̈1 = ω2² (v - r1 - 2ζ2 r2), v = slope z + w
        y_r1 = a2 * (1.0 - k)
        y_r2 = a2 * (2.0 * zz * w2 / wz - 2.0 * z2 * k)
        rows = [
            [o, w1, o, o, o, o],
            [-w1, -2.0 * z1 * w1, o, o, o, o],
            [a1, o, -a1, o, o, o],
            [o, o, o, o, w2, o],
            [o, o, w2 * slope, -w2, -2.0 * z2 * w2, o],
            [o, o, a2 * k * slope, y_r1, y_r2, -a2],
        ]
        a = torch.stack([torch.stack(row) for row in rows])
        b = torch.stack([o, w1, o, o, o, o]).reshape(6, 1)
        c = torch.stack([o, o, o, o, o, torch.ones_like(w1)]).reshape(1, 6)
        e = torch.stack([o, o, o, o, o, a2 * v["output_offset"]])  # y settles at its input plus the offset
        return StateSpace(a, b, c, w1.new_zeros(1, 1), e)

    def feedback(self, p: Mapping[str, Tensor]) -> Tensor:
        v = self._values(p)
        w2, wz, a2 = TWO_PI * v["second_frequency_hz"], TWO_PI * v["notch_frequency_hz"], TWO_PI * v["second_pole_hz"]
        o = torch.zeros_like(w2)
        return torch.stack([o, o, o, o, w2, a2 * w2 * w2 / (wz * wz)]).reshape(6, 1)

    def nonlinearity(self, x: Tensor, u: Tensor, p: Mapping[str, Tensor]) -> Tensor:
        names = self._names  # twice a sample: read the knee's three values only, no dict of all of them
        return knee(x[..., 2:3], p[names["slope_change"]], p[names["knee"]], p[names["knee_width"]])
