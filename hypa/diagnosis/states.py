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
from hypa.models.rollout import model_inputs
from hypa.physics import LTIBlock

if TYPE_CHECKING:
    from hypa.data import HypaDataModule


def state_scales(model: ComposedModel, dm: HypaDataModule | None = None,
                 blocks: Collection[str] | None = None) -> dict[str, tuple[float, float, float, float]]:
    """Each physics block's states (``<block>/<state>``) -> (operating point, spread) [SI]: the
    scaling the model gave them (a measured state's from the data, another's from the physics);
    then (``low``, ``high``) [SI]: with ``dm``, for the states of ``blocks`` (all: None), their 10th
    and 90th percentiles in the model's free runs over the training records (where a state that
    no sensor reads actually goes, which its scaling's spread may miss by a factor), else the
    operating point ∓ the spread."""
    out: dict[str, tuple[float, float, float, float]] = {}
    for name, block in model.blocks.items():
        if isinstance(block, LTIBlock):
            for state, mean, std in zip(block.model.state_names, block.state_mean.tolist(), block.state_std.tolist()):
                out[f"{name}/{state}"] = (float(mean), float(std), float(mean - std), float(mean + std))
    started = [n for n in model.started_blocks() if blocks is None or n in blocks]
    if dm is None or not started:
        return out
    runs: dict[str, list[np.ndarray]] = {n: [] for n in started}
    with torch.no_grad():
        for record in dm.records("train"):
            states: dict[str, torch.Tensor] = {}
            model.signals(*model_inputs(dm, record), states=states)
            for name in started:
                block = model.blocks[name]
                physical = states[name][0].double() * block.state_std + block.state_mean
                runs[name].append(physical.numpy())
    for name, parts in runs.items():
        values = np.concatenate(parts)
        for j, state in enumerate(model.blocks[name].model.state_names):
            finite = values[:, j][np.isfinite(values[:, j])]
            low, high = np.percentile(finite, [10, 90]) if finite.size else (0.0, 0.0)
            if high > low:  # else (a state the free runs never move) the scaling's
                out[f"{name}/{state}"] = (*out[f"{name}/{state}"][:2], float(low), float(high))
    return out
