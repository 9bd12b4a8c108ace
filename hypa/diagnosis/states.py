"""What a catalogue entry reads of a model's states: operating point, spread, free-run range.

``for_each: state`` entries start their values from these (a limit at the state's 90th
percentile), ``for_each: block`` entries read their block's (``position_spread``). They come
from the round's model, not the nominal one: a state no sensor reads moves with the values
fitted so far.
"""

from __future__ import annotations

from collections.abc import Collection
from typing import TYPE_CHECKING

import numpy as np
import torch

from hypa.models import ComposedModel
from hypa.physics import LTIBlock

if TYPE_CHECKING:
    from hypa.identification.stretches import Stretches


def state_scales(model: ComposedModel, stretches: Stretches | None = None,
                 blocks: Collection[str] | None = None) -> dict[str, tuple[float, float, float, float]]:
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
    stretch's length in steps, not a whole record's."""
    out: dict[str, tuple[float, float, float, float]] = {}
    for name, block in model.blocks.items():
        if isinstance(block, LTIBlock):
            for state, mean, std in zip(block.model.state_names, block.state_mean.tolist(), block.state_std.tolist()):
                out[f"{name}/{state}"] = (float(mean), float(std), float(mean - std), float(mean + std))
    started = [n for n in model.started_blocks() if blocks is None or n in blocks]
    if stretches is None or not started:
        return out
    runs: dict[str, list[np.ndarray]] = {n: [] for n in started}
    ran: list[dict[str, torch.Tensor]] = []
    with torch.no_grad():
        stretches.predict(model, states=ran)
    for states in ran:
        for name in started:
            block = model.blocks[name]
            physical = states[name].double() * block.state_std + block.state_mean
            runs[name].append(physical.reshape(-1, physical.shape[-1]).numpy())
    for name, parts in runs.items():
        values = np.concatenate(parts)
        for j, state in enumerate(model.blocks[name].model.state_names):
            finite = values[:, j][np.isfinite(values[:, j])]
            low, high = np.percentile(finite, [10, 90]) if finite.size else (0.0, 0.0)
            if not high > low:  # a state the free runs never move: the scaling's
                continue
            key = f"{name}/{state}"
            scale = out[key][:2] if j in model.blocks[name].observed_states else (finite.mean(), finite.std())
            out[key] = (float(scale[0]), float(scale[1]), float(low), float(high))
    return out
