"""What a catalogue entry reads of a model's states: operating point, spread, free-run range, and
the levels a limit on it starts at.

``for_each: state`` entries start their values from these (a limit where the data stop a state a
sensor reads, else at the state's 90th percentile), ``for_each: block`` entries read their block's
(``position_spread``). They come from the round's model, not the nominal one: a state no sensor
reads moves with the values fitted so far.
"""

from __future__ import annotations

from collections.abc import Collection
from typing import TYPE_CHECKING

import numpy as np
import torch

from hypa.models import ComposedModel
from hypa.models.building import ESTIMATE, MEASURED
from hypa.physics import LTIBlock

if TYPE_CHECKING:
    from hypa.identification.stretches import Stretches


Scales = tuple[float, float, float, float, float, float]  # level, spread, low, high, bottom, top [SI]


def state_scales(model: ComposedModel, stretches: Stretches | None = None,
                 blocks: Collection[str] | None = None) -> dict[str, Scales]:
    """Each physics block's states (``<block>/<state>``) -> (operating point, spread) [SI]: a
    measured state's (or one a measured output reads alone) from the data, the model's scaling;
    then (``low``, ``high``) [SI]: with ``stretches`` (the training records cut into the search's
    scoring stretches, each started from the data), for the states of ``blocks`` (all: None), their
    10th and 90th percentiles in the model's free runs over them (where a state that no sensor reads
    actually goes, which its scaling's spread may miss by a factor), else the operating point ∓ the
    spread. A state no sensor reads takes its operating point and spread from those free runs too
    (their mean and standard deviation): its scaling is the physics', about 0 for a linear block
    (an upper tank's level at 0 ± 0.3 V that its free run puts at 4.4 ± 1.2 V). The stretches run
    side by side: a model simulated step by step (a curved state, a direction-dependent gain) takes a
    stretch's length in steps, not a whole record's.

    Then (``bottom``, ``top``) [SI], where a limit on the state starts: for a state a measured output
    reads alone, the smallest and largest value the data show over the stretches (a sensor that reads
    10.0 V on every sample of a plateau: the level the state stops at; a limit there is passed only
    where the model overshoots the data, so the fit sees it), else ``low`` and ``high`` (a limit at
    the free run's 90th percentile of a state the data cannot show)."""
    out: dict[str, Scales] = {}
    for name, block in model.blocks.items():
        if isinstance(block, LTIBlock):
            for state, mean, std in zip(block.model.state_names, block.state_mean.tolist(), block.state_std.tolist()):
                low, high = float(mean - std), float(mean + std)
                out[f"{name}/{state}"] = (float(mean), float(std), low, high, low, high)
    started = [n for n in model.started_blocks() if blocks is None or n in blocks]
    if stretches is None or not started:
        return out
    for name, values in stretches.physical_states(model, started).items():
        for j, state in enumerate(model.blocks[name].model.state_names):
            finite = values[:, j][np.isfinite(values[:, j])]
            low, high = np.percentile(finite, [10, 90]) if finite.size else (0.0, 0.0)
            if not high > low:  # a state the free runs never move: the scaling's
                continue
            key = f"{name}/{state}"
            scale = out[key][:2] if j in model.blocks[name].observed_states else (finite.mean(), finite.std())
            out[key] = (float(scale[0]), float(scale[1]), float(low), float(high), float(low), float(high))
    for key, (bottom, top) in measured_extremes(model, stretches, started).items():
        out[key] = (*out[key][:4], bottom, top)
    return out


def measured_extremes(model: ComposedModel, stretches: Stretches,
                      blocks: Collection[str]) -> dict[str, tuple[float, float]]:
    """``<block>/<state>`` -> (smallest, largest) value of the state that the data show [SI], for the
    states of ``blocks`` that a measured output reads alone (measured at a window start, or an
    observed output whose row of C has one nonzero entry and no feedthrough)."""
    reads: dict[str, tuple[int, str, float]] = {}  # key -> (column, channel, gain: output / state)
    for name in blocks:
        block, how = model.blocks[name], model.starts.get(name)
        if not isinstance(block, LTIBlock) or how is None or block.model.has_nonlinear_output:
            continue
        states = block.model.state_names
        if how.mode == MEASURED:
            reads.update({f"{name}/{states[j]}": (column, channel, 1.0)
                          for j, (column, channel) in enumerate(zip(how.index, how.measured))})
        elif how.mode == ESTIMATE:
            ss = block.state_space()
            for i, channel in enumerate(how.observed):
                row = ss.c[i]
                nonzero = torch.nonzero(row).flatten().tolist()
                if channel is not None and len(nonzero) == 1 and not torch.count_nonzero(ss.d[i]):
                    reads[f"{name}/{states[nonzero[0]]}"] = (how.index[i], channel, float(row[nonzero[0]]))
    if not reads or not stretches.batches:
        return {}
    y = torch.cat([b["y"].reshape(-1, b["y"].shape[-1]) for b in stretches.batches]).double()
    out = {}
    for key, (column, channel, gain) in reads.items():
        mean, std = model.measured_scale[channel]
        values = (y[:, column] * std + mean) / gain
        values = values[torch.isfinite(values)]
        if values.numel():
            out[key] = (float(values.min()), float(values.max()))
    return out
