"""What the frozen blocks of a composition computed, kept per window while networks train.

In a hybrid's later stages the physics is identified and frozen: only the networks train. The
physics blocks then compute, every epoch, the same outputs from the same windows: on a nonlinear
block run step by step (a Lur'e loop, a diode) that is most of an epoch (the Wiener-Hammerstein
circuit: 85 % of a training step). :class:`FrozenMemo` keeps them.

What is frozen is read from the model at each call (:meth:`ComposedModel.frozen_blocks`): no
physical parameter trains, and the block is a physics, FMU or element block (or a bypassed network)
fed only by measured signals and other frozen blocks. An entry is found by the window's contents
(a digest of its inputs, past outputs and scheduling signals, bytes and shape), never by its
position in a data set, and belongs to the parameters' values it was computed with: another value
(the best epoch's weights restored, a later identification), another frozen set or device empties
the memo. So a memo returns what the blocks compute now, to round-off: a window is computed once,
without a graph and in the batch that first holds it (``hypa.physics.scan`` sums in another order
without a graph; a float32 circuit's outputs differ by about 1e-4 of its spread).

Entries are kept in the host's memory (moved to the model's device when read), bounded by
``budget`` bytes: a sixteenth of what this process may still allocate (``hypa.core.machine``; a
control group's limit counts), shared by the processes of one machine (``LOCAL_WORLD_SIZE`` under
DDP). Windows past it are computed each time, as without a memo.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable, Sequence

import torch
from torch import Tensor

Signal = tuple[Tensor, int]
Run = Callable[[Tensor, Tensor, Tensor | None], dict[str, Signal]]  # the frozen blocks on some windows


ENTRY_OVERHEAD = 256  # bytes a kept tensor costs beyond its values (the object, its storage, the dict's slot)


def default_budget() -> int:
    """A sixteenth of the memory this process may still allocate [bytes], shared by the processes
    of this machine (``LOCAL_WORLD_SIZE``); 1 GiB where the machine does not say."""
    from hypa.core.machine import available_memory

    try:
        processes = max(1, int(os.environ.get("LOCAL_WORLD_SIZE", "1")))
    except ValueError:
        processes = 1
    room = available_memory()
    return (1 << 30) // processes if room is None else room // 16 // processes


class FrozenMemo:
    """Frozen blocks' output signals by window contents (module docstring). ``hits`` and
    ``misses`` count windows; ``kept`` is the bytes held."""

    def __init__(self, budget: int | None = None) -> None:
        self.budget = default_budget() if budget is None else int(budget)
        self.entries: dict[bytes, dict[str, Signal]] = {}
        self.kept, self.hits, self.misses = 0, 0, 0
        self._version: tuple | None = None
        self._values: Tensor | None = None

    def clear(self) -> None:
        self.entries.clear()
        self.kept = 0

    def signals(self, version: tuple, values: Tensor, u: Tensor, y_past: Tensor, s: Tensor | None,
                run: Run) -> dict[str, Signal]:
        """The frozen blocks' signals of each window of the batch (B rows): those kept, and ``run`` on
        the others (whose results are kept while the budget allows). ``version``: what else the
        results depend on (the frozen blocks, dtype, device); ``values``: the parameters' values."""
        if version != self._version or self._values is None or not torch.equal(values, self._values):
            self.clear()
            self._version, self._values = version, values.detach().clone()
        keys = _digests(u, y_past, s)
        missing = [i for i, k in enumerate(keys) if k not in self.entries]
        self.hits += len(keys) - len(missing)
        self.misses += len(missing)
        computed: dict[str, Signal] = {}
        if missing:
            rows = torch.as_tensor(missing, device=u.device)
            with torch.no_grad():
                computed = run(*(None if t is None else t.index_select(0, rows) for t in (u, y_past, s)))
            self._keep([keys[i] for i in missing], computed)
            if len(missing) == len(keys):
                return computed
        fresh = {i: j for j, i in enumerate(missing)}  # batch row -> row of `computed`
        first = self.entries[keys[next(i for i in range(len(keys)) if i not in fresh)]]
        return {name: (torch.stack([computed[name][0][fresh[i]] if i in fresh
                                    else self.entries[k][name][0].to(u.device, non_blocking=True)
                                    for i, k in enumerate(keys)]), start)
                for name, (_, start) in first.items()}

    def _keep(self, keys: Sequence[bytes], computed: dict[str, Signal]) -> None:
        """Row j of ``computed`` kept under ``keys[j]``, while the budget allows."""
        for j, key in enumerate(keys):
            entry = {name: (values[j].detach().to("cpu", copy=True), start)
                     for name, (values, start) in computed.items()}
            size = sum(v.numel() * v.element_size() + ENTRY_OVERHEAD for v, _ in entry.values())
            if self.kept + size > self.budget:
                return
            self.entries[key] = entry
            self.kept += size


def _digests(u: Tensor, y_past: Tensor, s: Tensor | None) -> list[bytes]:
    """One digest per window (row) of its inputs, past outputs and scheduling signals: their
    dtypes, shapes and bytes."""
    parts = [t.detach().contiguous().cpu() for t in (u, y_past, s) if t is not None]
    head = repr([(str(t.dtype), tuple(t.shape[1:])) for t in parts]).encode()
    arrays = [t.reshape(t.shape[0], -1).view(torch.uint8).numpy() if t.numel() else None for t in parts]
    keys = []
    for i in range(u.shape[0]):
        digest = hashlib.blake2b(head, digest_size=20)
        for a in arrays:
            if a is not None:
                digest.update(a[i].tobytes())
        keys.append(digest.digest())
    return keys
