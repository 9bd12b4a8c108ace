"""Scheduled (linear parameter-varying) physics: matrices that change every sample with a measured signal.

A scheduled parameter (a vehicle's velocity) follows a measured signal ρ instead of staying
constant. The block holds ρ like a zero-order hold: over sample j (t_j <= t < t_{j+1}) the
continuous matrices are those at ρ_j, so step j -> j+1 is the exact discretization, with the
block's input hold, of A(ρ_j), B(ρ_j), e(ρ_j), and eq. 5 gets per-sample matrices:

    x̂_{j+1} = Â_j x̂_j + Σ_t B̂_{t,j} û_{j+t} + Ĥ_j,        ŷ_j = Ĉ_j x̂_j + D̂_j û_j + Ĝ_j

(the output matrices at ρ_j, the sample they belong to). Freezing the matrices over a sample is
the only approximation: a ρ that moves within a sample is seen as a staircase, a first-order
error in dt dρ/dt. Measured for the velocity-scheduled single track (dt = 1/32 s, v ramping
5 -> 30 m/s in 4 s, i.e. 6.25 m/s², random steering) against a reference of 64 exact substeps
per sample with v interpolated linearly: 0.45 % (ZOH) / 0.49 % (FOH) of the states' RMS
(``test_physics_scheduled``); it shrinks in proportion to dt dρ/dt, and at a constant ρ the
scheduled block is exact.

The lifted form (eq. 9-11) needs one Â; here every step has its own. The steps are the affine
maps f_j(x) = Φ_j x + c_j (c_j = Σ_t B̂_{t,j} û_{j+t} + Ĥ_j), and composition is associative,

    (f_j ∘ f_i)(x) = Φ_j Φ_i x + (Φ_j c_i + c_j),

so all prefix compositions F_j = f_j ∘ ... ∘ f_0 come from a parallel-prefix scan in ⌈log2 N⌉
batched steps (``hypa.physics.scan``) instead of N dependent ones, and x̂_{j+1} = F_j(x̂_0): exact.
Its gradient is the adjoint recursion run as the same scan backwards, reusing the forward's
products (``scan._AffineStates``). Cost at N = 100, batch 32 (``hypa timing physics``): the batched
hold (``NormalizingMaps.state_rows``, φ-functions of the n x n A dt) and the scan take about a
third of the forward each; the per-sample matrices (``per_sample_matrices``) about a tenth when
the system's code is batch-safe (one plain call, verified once against vmap: ``batch_layout``),
a third with ``torch.func.vmap`` otherwise. The scan is about 4x faster than a python loop over
the samples forward, and its hand-written adjoint over 10x faster than differentiating that loop.
"""

from __future__ import annotations

import logging
import math
import weakref
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from hypa.core.errors import UserError
from hypa.physics.scan import _AffineStates, _apply, _scan
from hypa.physics.statespace import LTIModel, StateSpace


class SchedulingError(UserError):
    """Scheduling signals that do not fit a block, or matrices that cannot be evaluated per sample."""


def per_sample_matrices(model: LTIModel, fixed: Mapping[str, Tensor], scheduled: Sequence[str],
                        rho: Tensor) -> StateSpace:
    """A, B, C, D, e of ``model`` at every sample of ``rho`` (..., q): each (..., rows, cols), e (..., n).

    ``matrices`` is the user's scalar code, evaluated for all K samples at once with the
    scheduled parameters taken from ``rho`` (in the order of ``scheduled``) and the others from
    ``fixed`` (scalars, trainable ones with their graph); e is zeros where None. Two ways to the
    same values and gradients:

    - batched: one plain call of ``matrices`` with every parameter a 1-D tensor of the K samples
      (the fixed ones expanded), where ``batch_layout`` has verified once that the system's code
      is batch-safe (the rule is there; the single track follows it): no per-op overhead;
    - ``torch.func.vmap`` of the scalar code otherwise (any code torch.func can batch), and for
      K < 2 or a K equal to a matrix dimension, where a batch layout could be misread.
    """
    lead, flat = rho.shape[:-1], rho.reshape(-1, rho.shape[-1])  # (K, q)
    samples = flat.shape[0]
    layout = batch_layout(model, fixed, scheduled, flat) if samples >= 2 else None
    if layout is not None and layout.fits(samples):
        try:
            return StateSpace(*layout.arrange(_batched(model, fixed, scheduled, flat), tuple(lead)))
        except Exception as error:  # noqa: BLE001 -- verified, yet not batch-safe after all: vmap
            _forget(model, fixed, scheduled, flat, error)
    return StateSpace(*(m.reshape(*lead, *m.shape[1:]) for m in _vmapped(model, fixed, scheduled, flat)))


def _vmapped(model: LTIModel, fixed: Mapping[str, Tensor], scheduled: Sequence[str],
             flat: Tensor) -> tuple[Tensor, ...]:
    """A, B, C, D, e (K, ...) at the samples ``flat`` (K, q) by ``torch.func.vmap`` of the scalar code."""
    def one(r: Tensor) -> tuple[Tensor, ...]:
        ss = model.matrices({**fixed, **dict(zip(scheduled, r.unbind()))})
        e = ss.e if ss.e is not None else ss.a.new_zeros(ss.a.shape[-1])
        return ss.a, ss.b, ss.c, ss.d, e

    try:
        return torch.func.vmap(one)(flat)
    except Exception as error:  # a user's code: say which call failed, in one line
        raise SchedulingError(f"{model.display_name}.matrices cannot be evaluated per sample with "
                              f"torch.func.vmap for scheduled {list(scheduled)}: {type(error).__name__}: "
                              f"{str(error).splitlines()[0] if str(error) else ''}") from error


def _batched(model: LTIModel, fixed: Mapping[str, Tensor], scheduled: Sequence[str],
             flat: Tensor) -> tuple[Tensor | None, ...]:
    """``matrices`` called once with every parameter a (K,) tensor: A, B, C, D, e as the code returns them."""
    samples = flat.shape[0]
    p = {name: value.expand(samples) for name, value in fixed.items()}  # a view: its gradient sums over K
    p.update(zip(scheduled, flat.unbind(-1)))
    ss = model.matrices(p)
    return ss.a, ss.b, ss.c, ss.d, ss.e


class _NotBatchSafe(Exception):
    """A system's ``matrices`` does not give its batch in a layout ``BatchLayout`` reads."""


_MATRICES = ("A", "B", "C", "D", "e")


@dataclass(frozen=True)
class BatchLayout:
    """Where the K samples sit in what ``matrices`` returns when every parameter is a (K,) tensor.

    Per matrix (A, B, C, D, e) its per-sample shape s and its place: ``leading`` (K, *s),
    ``trailing`` (*s, K) (what ``torch.stack`` of batched scalar entries gives), ``constant``
    s (an entry that depends on no parameter, as ``torch.eye``; the same at every sample) or
    ``none`` (e is None: zeros).
    """

    shapes: tuple[tuple[int, ...], ...]
    places: tuple[str, ...]

    @staticmethod
    def shape_at(place: str, shape: tuple[int, ...], samples: int) -> tuple[int, ...]:
        """The shape a matrix of per-sample shape ``shape`` has at its ``place`` in a batch of K = ``samples``."""
        return {"leading": (samples, *shape), "trailing": (*shape, samples)}.get(place, shape)

    @staticmethod
    def read(outputs: Sequence[Tensor | None], shapes: Sequence[tuple[int, ...]], samples: int) -> BatchLayout:
        """The layout of ``outputs`` (``_batched`` at ``samples`` points) whose per-sample shapes are ``shapes``."""
        places = []
        for name, out, shape in zip(_MATRICES, outputs, shapes):
            found = ["none"] if out is None and name == "e" else [
                place for place in ("leading", "trailing", "constant")
                if out is not None and out.shape == BatchLayout.shape_at(place, shape, samples)]
            if not found:
                raise _NotBatchSafe(f"{name} is {None if out is None else tuple(out.shape)}, not "
                                    f"(K, *s), (*s, K) or s for s = {shape} and K = {samples}")
            places.append(found[0])  # one only: K is no matrix dimension
        return BatchLayout(tuple(tuple(s) for s in shapes), tuple(places))

    def fits(self, samples: int) -> bool:
        """Whether K samples read unambiguously: K >= 2 and no matrix dimension equals K."""
        return samples >= 2 and all(samples not in shape for shape in self.shapes)

    def arrange(self, outputs: Sequence[Tensor | None], lead: tuple[int, ...]) -> tuple[Tensor, ...]:
        """A, B, C, D, e as (*lead, *s) (views; K = prod(lead)); ``_NotBatchSafe`` on a shape off the layout."""
        samples, mats = math.prod(lead), []
        for name, out, shape, place in zip(_MATRICES, outputs, self.shapes, self.places):
            if place == "none" and out is None:
                mats.append(outputs[0].new_zeros(()).expand(*lead, *shape))
                continue
            expected = self.shape_at(place, shape, samples)
            if out is None or place == "none" or out.shape != expected:
                raise _NotBatchSafe(f"{name} is {None if out is None else tuple(out.shape)}, not {expected}")
            mats.append(out.movedim(-1, 0).reshape(*lead, *shape) if place == "trailing" else
                        out.expand(*lead, *shape) if place == "constant" else out.reshape(*lead, *shape))
        return tuple(mats)


_LOG = logging.getLogger(__name__)
_CHECK_POINTS = 5  # samples the batched call is checked at (more where a matrix dimension equals it)
# id(model) -> (a weak reference to it, {(scheduled, fixed names, dtype, device): BatchLayout or None (vmap)})
_DECISIONS: dict[int, tuple[weakref.ref, dict[tuple, BatchLayout | None]]] = {}


def batch_layout(model: LTIModel, fixed: Mapping[str, Tensor], scheduled: Sequence[str],
                 flat: Tensor) -> BatchLayout | None:
    """The verified ``BatchLayout`` of ``model.matrices``, or None where ``per_sample_matrices`` must use vmap.

    The rule: ``matrices`` is batch-safe when, called with every parameter a 1-D tensor of K
    samples instead of a 0-d one, it computes every sample's matrices independently and returns
    each matrix as (K, *s), (*s, K) or, for an entry that depends on no parameter, s. Code that
    computes each entry elementwise (arithmetic, torch functions, ``torch.where``) and builds
    the matrices with ``torch.stack`` (``torch.stack(...)[:, None]`` broadcasting, slicing and
    sums over matrix dims included) is; a ``reshape`` or matmul of batched entries, a python
    ``float()``/``if`` on a value, or a reduction over the samples is not.

    Nothing is taken on trust: on the first call for a key (the model instance, the scheduled
    and fixed names, dtype, device) the batched call's result is compared with vmap's, values
    to 64 ulp (of the dtype, relative to the matrix's largest entry) and gradients with respect
    to the scheduled values and the fixed parameters to 1024 ulp, at ``_CHECK_POINTS`` distinct
    points (``_check_points``; one more than the largest matrix dimension where one equals it). Any
    exception, shape off the layout or mismatch gives None, remembered for the key (a debug log
    says why), as does a later failure of the batched call (``_forget``). The decision costs
    about two vmap evaluations and two backward passes, once. A model that cannot be weakly
    referenced is not remembered and always uses vmap.
    """
    decisions = _decisions(model, create=True)
    if decisions is None:  # no weak reference to it
        return None
    key = _key(fixed, scheduled, flat)
    if key not in decisions:
        decisions[key] = _decide(model, fixed, scheduled, flat)
    return decisions[key]


def _decisions(model: LTIModel, create: bool = False) -> dict[tuple, BatchLayout | None] | None:
    """``model``'s decisions by key (``_key``), a new empty dict with ``create``; None where there are none."""
    entry = _DECISIONS.get(id(model))
    if (entry is None or entry[0]() is not model) and create:
        key = id(model)
        try:
            ref = weakref.ref(model, lambda _: _DECISIONS.pop(key, None))
        except TypeError:
            return None
        entry = _DECISIONS[key] = (ref, {})
    return entry[1] if entry is not None and entry[0]() is model else None


def _key(fixed: Mapping[str, Tensor], scheduled: Sequence[str], flat: Tensor) -> tuple:
    return tuple(scheduled), tuple(sorted(fixed)), flat.dtype, flat.device


def batch_decisions(model: LTIModel) -> dict[tuple, bool]:
    """What ``batch_layout`` decided for ``model`` so far: {(scheduled, fixed names, dtype, device): batched}."""
    return {key: layout is not None for key, layout in (_decisions(model) or {}).items()}


def _forget(model: LTIModel, fixed: Mapping[str, Tensor], scheduled: Sequence[str], flat: Tensor,
            error: Exception) -> None:
    """vmap from now on for this key: the batched call failed after its verification."""
    _LOG.debug("%s.matrices: the batched call failed for scheduled %s (%s), vmap from now on: %s: %s",
               model.display_name, list(scheduled), flat.dtype, type(error).__name__, error)
    decisions = _decisions(model)
    if decisions is not None:
        decisions[_key(fixed, scheduled, flat)] = None


def _decide(model: LTIModel, fixed: Mapping[str, Tensor], scheduled: Sequence[str],
            flat: Tensor) -> BatchLayout | None:
    """``_verify``, any failure (the system's or the check's) a None with a debug log."""
    try:
        if any(value.dim() != 0 for value in fixed.values()):
            raise _NotBatchSafe("a fixed parameter is not a scalar")
        with torch.inference_mode(False), torch.enable_grad():  # the check compares gradients too
            layout = _verify(model, fixed, scheduled, flat)
    except Exception as error:  # noqa: BLE001 -- whatever the user's code raises means vmap
        _LOG.debug("%s.matrices is evaluated per sample with vmap for scheduled %s (%s): %s: %s",
                   model.display_name, list(scheduled), flat.dtype, type(error).__name__, error)
        return None
    _LOG.debug("%s.matrices is batch-safe for scheduled %s (%s): %s", model.display_name, list(scheduled),
               flat.dtype, dict(zip(_MATRICES, layout.places)))
    return layout


def _verify(model: LTIModel, fixed: Mapping[str, Tensor], scheduled: Sequence[str], flat: Tensor) -> BatchLayout:
    """The batched call's layout, after its values and gradients equal vmap's at a few points; else raises."""
    leaves = {k: v.detach().clone().requires_grad_(v.is_floating_point() or v.is_complex()) for k, v in fixed.items()}
    points = _check_points(flat, _CHECK_POINTS)
    reference = _vmapped(model, leaves, scheduled, points)
    dims = {d for r in reference for d in r.shape[1:]}
    if _CHECK_POINTS in dims:  # K equal to a matrix dimension could hide a mixed-up layout
        points = _check_points(flat, max(dims) + 1)
        reference = _vmapped(model, leaves, scheduled, points)
    samples = points.shape[0]
    shapes = tuple(tuple(r.shape[1:]) for r in reference)
    outputs = _batched(model, leaves, scheduled, points)
    layout = BatchLayout.read(outputs, shapes, samples)
    got = layout.arrange(outputs, (samples,))
    for name, g, r in zip(_MATRICES, got, reference):
        if g.dtype != r.dtype or not _close(g, r, 64):
            raise _NotBatchSafe(f"{name} differs from vmap's")
    if [g.requires_grad for g in got] != [r.requires_grad for r in reference]:
        raise _NotBatchSafe("the batched matrices depend on other tensors than vmap's")
    inputs = [points, *(v for v in leaves.values() if v.requires_grad)]
    generator = torch.Generator(device=points.device).manual_seed(0)  # not the global stream
    weights = [torch.rand(r.shape, generator=generator, dtype=r.dtype, device=r.device) for r in reference]
    terms = [(w * r, w * g) for w, r, g in zip(weights, reference, got) if r.requires_grad]
    if terms:
        for name, g, r in zip(["scheduled", *(k for k, v in leaves.items() if v.requires_grad)],
                              torch.autograd.grad(sum(t[1].sum() for t in terms), inputs, allow_unused=True),
                              torch.autograd.grad(sum(t[0].sum() for t in terms), inputs, allow_unused=True)):
            if (g is None) != (r is None) or (r is not None and not _close(g, r, 1024)):
                raise _NotBatchSafe(f"the gradient with respect to {name} differs from vmap's")
    return layout


def _check_points(flat: Tensor, count: int) -> Tensor:
    """``count`` distinct scheduling points (count, q) near the given samples, a leaf that requires grad.

    Samples spread over ``flat`` scaled by 1 + i/(4 count), i = 1..count (zeros become i/(4 count),
    non-finite values 1), so each point differs from the others even for a constant signal.
    """
    with torch.no_grad():
        index = torch.linspace(0, flat.shape[0] - 1, count, device=flat.device).round().long()
        base = flat.detach()[index]
        base = torch.where(torch.isfinite(base), base, torch.ones_like(base))
        offset = torch.arange(1, count + 1, dtype=flat.dtype, device=flat.device)[:, None] / (4 * count)
        points = torch.where(base == 0, offset, base * (1 + offset))
    return points.clone().requires_grad_(True)


def _close(x: Tensor, reference: Tensor, ulps: float) -> bool:
    """``x`` equals ``reference`` to ``ulps`` units of the dtype, relative to each entry and to the largest one."""
    if x.shape != reference.shape:
        return False
    x, reference = x.detach(), reference.detach()
    if not (reference.is_floating_point() or reference.is_complex()):
        return bool(torch.equal(x, reference))
    tol = ulps * torch.finfo(reference.dtype).eps
    finite = reference.abs().nan_to_num(0.0, 0.0, 0.0)
    scale = float(finite.max()) if finite.numel() else 0.0
    return bool(torch.allclose(x, reference, rtol=tol, atol=tol * scale, equal_nan=True))


def forced_terms(v: Tensor, n_taps: int, u: Tensor, steps: int) -> Tensor:
    """c_j = Σ_t B̂_{t,j} û_{j+t} + Ĥ_j (B, steps, n), j = 0..steps-1.

    v: [B̂_0, ..., B̂_{T-1}, Ĥ] as (n, T m + 1) (constant) or (B, steps, n, T m + 1) (per step);
    u: (B, >= steps + T - 1, m). Per step, the sum runs with the sample index laid out last (a
    (B, steps, n) view of an (n, B, steps) tensor comes back): ``NormalizingMaps.state_rows``
    lays its stacks out that way, so no copy is made.
    """
    if v.dim() == 2:
        window = torch.cat([*(u[:, t : t + steps] for t in range(n_taps)), u.new_ones(u.shape[0], steps, 1)], -1)
        return window @ v.T  # (B, steps, n)
    last = u.permute(2, 0, 1)  # (m, B, L)
    window = torch.cat([*(last[..., t : t + steps] for t in range(n_taps)), u.new_ones(1, u.shape[0], steps)])
    return _apply(v.movedim((-2, -1), (0, 1)), window).movedim(0, -1)  # (n, B, steps) -> (B, steps, n)


def simulate_scheduled(rows: Tensor, n_taps: int, x0: Tensor, u: Tensor) -> Tensor:
    """States x̂_{1..S} (B, S, n) of x̂_{j+1} = Â_j x̂_j + Σ_t B̂_{t,j} û_{j+t} + Ĥ_j by a parallel-prefix scan.

    rows: (B, S, n, n + T m + 1) per-step [Â_j, B̂_{0,j}, ..., B̂_{T-1,j}, Ĥ_j]; x0: (B, n);
    u: (B, >= S + T - 1, m). x̂_0 is folded into the first step's forced term, then the states
    are ``_AffineStates`` (the scan of ``affine_scan`` with a hand-written adjoint); where no
    gradient is wanted, ``_untaped_states``.
    """
    if not (torch.is_grad_enabled() and (rows.requires_grad or x0.requires_grad or u.requires_grad)):
        return _untaped_states(rows, n_taps, x0, u)
    n, steps = x0.shape[-1], rows.shape[-3]
    phi, v = rows.split([n, rows.shape[-1] - n], -1)  # one graph node (its backward one cat), not two slices
    phi = phi.movedim((-2, -1), (0, 1))  # (n, n, B, S)
    c = forced_terms(v, n_taps, u, steps).movedim(-1, 0)  # (n, B, S)
    start = _apply(phi[..., 0], x0.T, c[..., 0])  # x̂_0 folded into the first map
    c = torch.cat([start[..., None], c[..., 1:]], -1)
    return _AffineStates.apply(phi.expand(n, n, *c.shape[1:]), c).movedim(0, -1)


def _untaped_states(rows: Tensor, n_taps: int, x0: Tensor, u: Tensor) -> Tensor:
    """``simulate_scheduled`` without a graph: the scan's first columns [c | Φ] (n, 1 + n, B, S) written in
    place (the forced terms and x̂_0 by ``addcmul``, no window copied), then its levels (``_scan``)."""
    n, (batch, steps), m = x0.shape[-1], rows.shape[:2], u.shape[-1]
    with torch.no_grad():
        z = rows.new_empty(n, n + 1, batch, steps)
        z[:, 1:] = rows[..., :n].permute(2, 3, 0, 1)
        v, c = rows[..., n:].permute(2, 3, 0, 1), z[:, 0]  # v (n, T m + 1, B, S), c (n, B, S)
        c.copy_(v[:, -1])  # Ĥ_j
        for t in range(n_taps):
            for i in range(m):
                c.addcmul_(v[:, t * m + i], u[:, t : t + steps, i])
        for i in range(n):
            c[..., 0].addcmul_(z[:, 1 + i, :, 0], x0[:, i])  # Â_0 x̂_0
        return _scan(z, prefix=False, keep=False)[1].permute(1, 2, 0)


def simulate_scheduled_recursive(rows: Tensor, n_taps: int, x0: Tensor, u: Tensor) -> Tensor:
    """The reference for ``simulate_scheduled``: one step after another (a python loop over samples)."""
    n, steps = x0.shape[-1], rows.shape[-3]
    c = forced_terms(rows[..., n:], n_taps, u, steps)
    x, out = x0, []
    for j in range(steps):
        x = (rows[:, j, :, :n] @ x[..., None]).squeeze(-1) + c[:, j]
        out.append(x)
    return torch.stack(out, 1)
