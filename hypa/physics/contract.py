"""Checking that a system follows the ``LTIModel`` contract, with one-line errors.

A user's system is a class in any importable module (``system: package.module:Class`` in a
model YAML); a mistake in it should surface as one sentence naming what is wrong, at build
time, not as a shape error deep inside a matrix exponential.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from hypa.core.errors import UserError
from hypa.physics.lti import LTIModel, StateSpace
from hypa.physics.parameters import ParameterSpec


class SystemContractError(UserError):
    """A system that cannot be used: unknown, not importable, or breaking the ``LTIModel`` contract."""


_NAME_GROUPS = ("state_names", "input_names", "output_names")


def check_system(system: object, where: str = "") -> None:
    """Raise ``SystemContractError`` unless ``system`` follows the ``LTIModel`` contract.

    Checks the signal and parameter declarations, then evaluates ``matrices`` at the nominal
    parameter values and checks the shapes (A (n, n), B (n, m), C (p, n), D (p, m), e (n,))
    and that every entry is finite. ``where`` names the system in the message (its import path).
    """
    label = where or type(system).__name__
    if not isinstance(system, LTIModel):
        kind = system.__name__ if isinstance(system, type) else type(system).__name__
        raise SystemContractError(f"system {label}: {kind} is not an instance of a hypa.physics.LTIModel subclass")
    for group in _NAME_GROUPS:
        _check_names(getattr(system, group, None), group, label)
    specs = getattr(system, "parameters", None)
    if isinstance(specs, ParameterSpec) or not isinstance(specs, Sequence):
        raise SystemContractError(f"system {label}: parameters must be a tuple of ParameterSpec, got {specs!r}")
    bad = [s for s in specs if not isinstance(s, ParameterSpec)]
    if bad:
        raise SystemContractError(f"system {label}: parameters must be ParameterSpec(name, value, unit, ...), "
                                  f"got {type(bad[0]).__name__} {bad[0]!r}")
    names = [s.name for s in specs]
    _check_unique(names, "parameter", label)
    missing = [n for n in system.parameter_names if n not in names]
    if missing:
        raise SystemContractError(f"system {label}: parameter_names {missing} have no ParameterSpec in parameters")
    _check_matrices(system, _nominal(specs), label)
    if system.is_nonlinear:
        _check_nonlinearity(system, _nominal(specs), label)
    if system.has_nonlinear_output:
        _check_output_nonlinearity(system, _nominal(specs), label)
    if system.outputs_are_states:
        _check_outputs_are_states(system, specs, label)


def _check_output_nonlinearity(system: LTIModel, nominal: dict[str, torch.Tensor], label: str) -> None:
    """h(x, u) at the nominal values and x = 0.5, u = 0.5 (inside a state of charge's range): shape (p,)
    for one sample and (2, p) for two, finite, elementwise in the leading dims, and differentiable."""
    n, m, p = len(system.state_names), len(system.input_names), len(system.output_names)
    where = f"system {label}: output_nonlinearity"
    if system.outputs_are_states:
        raise SystemContractError(f"{where}: its outputs are named like its states {list(system.state_names)}, so "
                                  "they are the states (y = x): give the measured outputs their own names")
    x = torch.full((n,), 0.5, dtype=torch.float64, requires_grad=True)
    u = torch.full((m,), 0.5, dtype=torch.float64, requires_grad=True)
    try:
        h = system.output_nonlinearity(x, u, nominal)
        shape = tuple(h.shape) if isinstance(h, torch.Tensor) else type(h).__name__
        if shape != (p,):
            raise SystemContractError(f"{where}(x ({n},), u ({m},), p) must return h of shape ({p},) (outputs), "
                                      f"got {shape}")
        two = system.output_nonlinearity(torch.stack([x.detach(), x.detach() * 0.9]),
                                         torch.stack([u.detach(), u.detach() * 0.9]), nominal)
        slopes = torch.autograd.grad(h.sum(), (x, u), allow_unused=True) if h.requires_grad else ()
    except SystemContractError:
        raise
    except Exception as error:  # a user's code: report any failure as one line
        raise SystemContractError(f"{where} raised {type(error).__name__}: {error}") from error
    if not bool(torch.isfinite(h).all()):
        raise SystemContractError(f"{where} is not finite at x = 0.5, u = 0.5 and the nominal values: "
                                  f"{h.tolist()}")
    if not isinstance(two, torch.Tensor) or tuple(two.shape) != (2, p) or not torch.allclose(two[0], h.detach()):
        raise SystemContractError(f"{where} must work on a batch of samples (x (..., {n}), u (..., {m}) -> (..., "
                                  f"{p})), elementwise in the leading dims (index x[..., j], not x[j])")
    if not all(g is None or bool(torch.isfinite(g).all()) for g in slopes):
        raise SystemContractError(f"{where} has a non-finite slope at x = 0.5, u = 0.5 (torch ops only, "
                                  "differentiable there)")


def _check_nonlinearity(system: LTIModel, nominal: dict[str, torch.Tensor], label: str) -> None:
    """F (n, r) and φ(x, u) (r,) at the nominal values, at rest and at a unit state and input."""
    n, m = len(system.state_names), len(system.input_names)
    try:
        f = system.feedback(nominal)
        w = system.nonlinearity(torch.ones(n, dtype=torch.float64) * 1e-2, torch.ones(m, dtype=torch.float64) * 1e-2,
                                system.prepare(nominal))
    except Exception as error:  # a user's code: report any failure as one line
        raise SystemContractError(f"system {label}: feedback / prepare / nonlinearity raised {type(error).__name__}: "
                                  f"{error}") from error
    if not isinstance(f, torch.Tensor) or f.dim() != 2 or f.shape[0] != n:
        raise SystemContractError(f"system {label}: feedback must return F of shape ({n}, r), got "
                                  f"{tuple(f.shape) if isinstance(f, torch.Tensor) else type(f).__name__}")
    if not isinstance(w, torch.Tensor) or tuple(w.shape) != (f.shape[1],):
        raise SystemContractError(f"system {label}: nonlinearity(x ({n},), u ({m},)) must return w of shape "
                                  f"({f.shape[1]},) to match F, got "
                                  f"{tuple(w.shape) if isinstance(w, torch.Tensor) else type(w).__name__}")
    if not (bool(torch.isfinite(f).all()) and bool(torch.isfinite(w).all())):
        raise SystemContractError(f"system {label}: feedback or nonlinearity is not finite at the nominal values")


def _check_outputs_are_states(system: LTIModel, specs: Sequence[ParameterSpec], label: str) -> None:
    """Outputs named like the states are taken as the states (y = x, C and D never applied): a C
    that is not I, or one that moves with a parameter, would be silently ignored, so refuse it.
    Checked at the nominal values and at every parameter moved by 5 % (or into its bounds)."""
    for values in (_nominal(specs), _nudged(specs)):
        try:
            ss = system.matrices(values)
        except Exception:  # noqa: BLE001, S112 -- the nudge left the system's domain: the nominal check above stands
            continue
        eye = torch.eye(len(system.state_names), dtype=ss.c.dtype)
        if not (torch.allclose(ss.c, eye) and bool((ss.d == 0).all())):
            raise SystemContractError(
                f"system {label}: its outputs are named like its states {list(system.state_names)}, so they are "
                "taken as the states (C = I, D = 0), but matrices returns another C or D (or one that depends on "
                "a parameter); give the measured outputs their own names")


def _nominal(specs: Sequence[ParameterSpec]) -> dict[str, torch.Tensor]:
    return {s.name: torch.tensor(s.value, dtype=torch.float64) for s in specs}


def _nudged(specs: Sequence[ParameterSpec]) -> dict[str, torch.Tensor]:
    out = {}
    for s in specs:
        value = s.value * 1.05 if s.value else 0.05
        if s.bounds is not None:
            lo, hi = s.bounds
            value = min(max(value, lo + 0.01 * (hi - lo)), hi - 0.01 * (hi - lo))
        out[s.name] = torch.tensor(value, dtype=torch.float64)
    return out


def _check_names(names: object, group: str, label: str) -> None:
    if names is None or (group != "state_names" and isinstance(names, Sequence) and len(names) == 0):
        raise SystemContractError(f"system {label}: missing {group} (a tuple of signal names)")
    if isinstance(names, str) or not isinstance(names, Sequence) or not all(isinstance(n, str) and n for n in names):
        raise SystemContractError(f"system {label}: {group} must be a tuple of non-empty strings, got {names!r}")
    _check_unique(list(names), group.removesuffix("_names"), label)


def _check_unique(names: list[str], what: str, label: str) -> None:
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise SystemContractError(f"system {label}: duplicate {what} names {twice}")


def _check_matrices(system: LTIModel, nominal: dict[str, torch.Tensor], label: str) -> None:
    try:
        ss = system.matrices(nominal)
    except Exception as error:  # a user's code: report any failure as one line
        raise SystemContractError(f"system {label}: matrices(nominal parameters) raised "
                                  f"{type(error).__name__}: {error}") from error
    if not isinstance(ss, StateSpace):
        raise SystemContractError(f"system {label}: matrices must return a StateSpace(a, b, c, d, e=None), "
                                  f"got {type(ss).__name__}")
    n, m, p = len(system.state_names), len(system.input_names), len(system.output_names)
    expected = {"A": ((n, n), "(states, states)"), "B": ((n, m), "(states, inputs)"),
                "C": ((p, n), "(outputs, states)"), "D": ((p, m), "(outputs, inputs)"), "e": ((n,), "(states,)")}
    for key, matrix in zip("ABCDe", (ss.a, ss.b, ss.c, ss.d, ss.e)):
        if matrix is None and key == "e":
            continue
        shape, meaning = expected[key]
        if not isinstance(matrix, torch.Tensor):
            raise SystemContractError(f"system {label}: matrices returned {key} as {type(matrix).__name__}, "
                                      f"expected a tensor of shape {shape} {meaning}")
        if tuple(matrix.shape) != shape:
            raise SystemContractError(f"system {label}: matrices returned {key} with shape {tuple(matrix.shape)}, "
                                      f"expected {shape} {meaning}")
        if not bool(torch.isfinite(matrix).all()):
            raise SystemContractError(f"system {label}: matrices returned a non-finite {key} at the nominal "
                                      f"parameters: {matrix.tolist()}")

