"""Defaults of a model's networks from its data: an end-to-end network's (``model=blackbox``) and a hybrid's.

A baseline is only honest if it is trained as well as its data allow, so its width, weight decay,
epoch budget and patience are not constants (which suit one data set and starve another) but follow
from the training data and the optimizer. ``hypa train`` fills in each one the configuration leaves
``null`` (a value given is kept):

- width (``ann=lstm``, ``ann=gru``): the width whose weights equal the training values (samples x outputs),
  about as many unknowns as data, rounded to the nearest power of two and at most the network's default width.
- weight decay: ``1 / V`` for ``V`` training values: a unit Gaussian prior on the weights, worth one
  training value (the loss is the mean squared error over the values, in the normalized scale).
- epoch budget: ``U / lr`` optimizer steps, in epochs of ``B`` batches: ``ceil(U / (lr B))``. NAdam
  moves a weight by about ``lr`` per step, so ``1 / lr`` steps move it by one unit of the normalized
  scale: the budget is ``U`` such units however many batches an epoch has (a short record has few,
  and 50 epochs of them are a few thousand steps; a long one has many, and needs fewer epochs).
- patience: ``0.4 U / lr`` steps, ``ceil(0.4 U / (lr B))`` epochs: the windows' validation loss jumps
  from epoch to epoch, and a patience of a few short epochs stops training after a few hundred steps.

``U`` is the run's ``budget`` (:data:`BUDGETS`): ``short`` (the default, ``U = 1``: a first run in
minutes) or ``full`` (``U = 5``, the benchmark's). On the test bench a hybrid's correction is within
0.0001 of its full budget's free-run R² after the short one (the full budget buys the last 15 % of the
windows' validation loss in five times the steps).

With the full budget the networks of a model with physics (a hybrid's correction) keep the paper's
settings (no weight decay, the network's own width, 50 epochs, patience 5), with the epoch budget and
the patience never below the same ``5 / lr`` and ``2 / lr`` steps: on Silverbox (345 batches an epoch)
that is the paper's 50 and 5, on the test bench (119 batches) 85 and 34, and on 1 024 samples every
4 s (5 batches) 2 000 epochs and a patience of 800, where a patience of 5 had stopped the correction
after its first epoch. With the short budget they take the derived ``1 / lr`` and ``0.4 / lr`` steps
alone (17 and 7 epochs on the test bench), and no weight decay.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from hypa.ann import GRUBlock, LSTMBlock, ann_hyperparameters, network_class
from hypa.models import ModelSpec, parse_model_spec

# NAdam's learning rates, the defaults of every way to train (hypa train's optimizer.lr and
# optimizer.physics_lr, HybridModule): the networks', and the physical parameters' (they live in
# log space, where a step is relative, so they take a larger one)
NETWORK_LR = 5e-4
PHYSICS_LR = 1e-2

# the epoch budget U per stage, in units of 1 / lr optimizer steps, by the run's ``budget``
BUDGETS = {"short": 1.0, "full": 5.0}
PATIENCE_SHARE = 0.4  # the patience, a share of the budget (2 / lr steps of the full 5)

# the recurrent networks whose width an end-to-end model derives from its data: their gates (weight
# blocks of h rows per layer), in torch's layout (nn.LSTM: i, f, g, o; nn.GRU: r, z, n)
RECURRENT_GATES: dict[type, int] = {LSTMBlock: 4, GRUBlock: 3}


@dataclass(frozen=True)
class TrainingDefaults:
    """What :func:`training_defaults` derives."""

    weight_decay: float
    max_epochs: int
    patience: int


def lstm_weights(hidden_size: int, d_in: int, d_out: int, num_layers: int = 1, gates: int = 4) -> int:
    """Weights of ``hypa.ann.LSTMBlock`` (``gates=4``) or ``hypa.ann.GRUBlock`` (``gates=3``), ``d_in`` its
    recurrent network's inputs: ``G h (d_in + h + 2)`` in the first layer (two bias vectors), ``G h (2 h + 2)``
    in each further one, ``d_out (h + 1)`` in the head."""
    h, g = hidden_size, gates
    return g * h * (d_in + h + 2) + (num_layers - 1) * g * h * (2 * h + 2) + d_out * (h + 1)


def matching_width(values: int, d_in: int, d_out: int, num_layers: int = 1, gates: int = 4) -> float:
    """The (real) width ``h`` whose :func:`lstm_weights` equal ``values``: the positive root of
    ``a h^2 + b h + d_out = values``, ``a = G + 2 G (L - 1)``, ``b = G (d_in + 2) + d_out + 2 G (L - 1)``."""
    a = gates + 2 * gates * (num_layers - 1)
    b = gates * (d_in + 2) + d_out + 2 * gates * (num_layers - 1)
    c = d_out - values
    return (-b + math.sqrt(b * b - 4 * a * c)) / (2 * a)


def lstm_width(values: int, d_in: int, d_out: int, widest: int, num_layers: int = 1, gates: int = 4) -> int:
    """The power of two nearest (on a log scale) the :func:`matching_width` for ``values`` training
    values (samples x outputs), at most ``widest``; 1 where the values do not pay for one unit."""
    if min(values, d_in, d_out, widest, num_layers, gates) < 1:
        raise ValueError(f"values, d_in, d_out, widest, num_layers and gates must be >= 1, "
                         f"got {values}, {d_in}, {d_out}, {widest}, {num_layers}, {gates}")
    matching = matching_width(values, d_in, d_out, num_layers, gates)
    if matching <= 1:
        return 1
    width = 2 ** round(math.log2(matching))
    while width > widest:
        width //= 2
    return max(width, 1)


def training_defaults(values: int, batches: int, lr: float, budget: str = "full") -> TrainingDefaults:
    """Weight decay, epoch budget and patience for ``values`` training values (samples x outputs),
    ``batches`` optimizer steps per epoch, the learning rate ``lr`` and the ``budget`` (:data:`BUDGETS`)."""
    if values < 1 or batches < 1:
        raise ValueError(f"values and batches per epoch must be >= 1, got {values}, {batches}")
    if not lr > 0:
        raise ValueError(f"lr must be > 0, got {lr}")
    if budget not in BUDGETS:
        raise ValueError(f"budget must be one of {', '.join(BUDGETS)}, got {budget!r}")
    units = BUDGETS[budget] / (lr * batches)  # epochs of U / lr optimizer steps
    # rounded first: 0.4 x 5 units is 2 units exactly, not 2.0000000000000004 (one epoch more)
    return TrainingDefaults(weight_decay=1.0 / values, max_epochs=max(1, math.ceil(round(units, 9))),
                            patience=max(1, math.ceil(round(PATIENCE_SHARE * units, 9))))


FIXED_DEFAULTS = {"weight_decay": 0.0, "max_epochs": 50, "patience": 5}  # the paper's, for a model with physics


def network_defaults(model: ModelSpec | dict[str, Any], ann_name: str, ann: dict[str, Any], dm: Any, lr: float,
                     weight_decay: float | None, epochs: int | None, patience: int | None,
                     limit_train_batches: float, budget: str = "full") -> tuple[dict[str, Any], float, int, int]:
    """The network settings, weight decay, epoch budget and patience, each ``None`` (null) one filled in.

    An end-to-end network (every block of the model a network: ``model=blackbox``) takes what
    :func:`training_defaults` derives from its training data (an LSTM's or a GRU's width too). The networks of a
    model with physics (a hybrid's correction) take no weight decay and the network's own defaults; with
    the ``full`` budget the paper's :data:`FIXED_DEFAULTS` (50 epochs, patience 5), but never fewer epochs
    or a shorter patience than the same ``5 / lr`` and ``2 / lr`` optimizer steps (on a short record 50
    epochs are a few hundred steps, and the correction stopped before it had learnt anything); with the
    ``short`` budget its ``1 / lr`` and ``0.4 / lr`` steps. A value set is kept."""
    accepted = ann_hyperparameters(ann_name)
    blocks = (model if isinstance(model, ModelSpec) else parse_model_spec(model)).blocks
    networks = [b for b in blocks if b.kind == "ann"]
    fixed = FIXED_DEFAULTS
    if networks:
        windows = len(dm.dataset("train"))
        batches = math.ceil(windows / dm.batch_size)
        limit = limit_train_batches  # Lightning's: a fraction of the batches (float) or a number of them (int)
        batches = max(1, min(batches, limit) if isinstance(limit, int) else int(batches * float(limit)))
        values = sum(len(r) for r in dm.records("train")) * len(dm.output_names)
        derived = training_defaults(values, batches, lr, budget)
        if len(networks) == len(blocks):
            fixed = derived.__dict__
            gates = RECURRENT_GATES.get(network_class(ann_name))
            if gates is not None and ann.get("hidden_size") is None:
                layers, projected = ann.get("num_layers") or accepted["num_layers"], ann.get("input_proj")
                ann["hidden_size"] = min(lstm_width(values, projected or len(b.inputs) + len(b.initial_state),
                                                    len(b.outputs), accepted["hidden_size"], layers, gates)
                                         for b in blocks)
        elif budget == "full":
            fixed = {**FIXED_DEFAULTS, "max_epochs": max(FIXED_DEFAULTS["max_epochs"], derived.max_epochs),
                     "patience": max(FIXED_DEFAULTS["patience"], derived.patience)}
        else:
            fixed = {**derived.__dict__, "weight_decay": FIXED_DEFAULTS["weight_decay"]}
    ann = {k: accepted[k] if v is None else v for k, v in ann.items()}  # the network's own default
    return (ann, fixed["weight_decay"] if weight_decay is None else weight_decay,
            fixed["max_epochs"] if epochs is None else epochs, fixed["patience"] if patience is None else patience)
