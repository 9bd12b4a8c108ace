"""ANN blocks: the sequence contract (shapes, causality, chunking with state, zero init,
gradients), the registry and its configs, the math of the GRU, S4D and selective-scan cores, a
small learning check per block, and the GRU through the command line (train, export)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from hypa.ann import (
    ANN_BLOCKS,
    GRUBlock,
    S4DKernel,
    SequenceBlock,
    ann_hyperparameters,
    build_ann,
    selective_scan,
    target,
)
from hypa.ann.s4 import causal_convolution
from hypa.conf import CONF

from cli_helpers import hypa_run
from conftest import SHORT_OVERRIDES

NAMES = sorted(ANN_BLOCKS)
# Every block with its defaults, plus non-default settings that take other code paths.
VARIANTS = [pytest.param(name, {}, id=name) for name in NAMES] + [
    pytest.param("lstm", {"input_proj": 8, "num_layers": 2}, id="lstm-proj-2layers"),
    pytest.param("gru", {"input_proj": 8, "num_layers": 2}, id="gru-proj-2layers"),
    pytest.param("transformer", {"context": 7, "n_heads": 3, "d_model": 12}, id="transformer-7"),
    pytest.param("s4", {"init": "inv", "n_layers": 1}, id="s4-inv"),
    pytest.param("mamba", {"d_conv": 1, "expand": 2, "dt_rank": 3}, id="mamba-noconv-x2"),
]
CONF_ANN = CONF / "ann"


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    """These small models run faster on one intra-op thread; two threads on a shared 2-core
    machine were measured up to 10x slower (threads waiting for each other)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def make(name: str, d_in: int = 2, d_out: int = 1, dtype: torch.dtype = torch.float32,
         seed: int = 0, **hparams: object) -> SequenceBlock:
    torch.manual_seed(seed)
    return build_ann(name, d_in, d_out, **hparams).to(dtype).eval()


def random_input(batch: int, length: int, d_in: int, dtype: torch.dtype = torch.float32,
                 seed: int = 1) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(batch, length, d_in, generator=g, dtype=dtype)


# -- the contract ----------------------------------------------------------------------------
@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("batch,length,d_in,d_out",
                         [(2, 17, 1, 1), (3, 1, 3, 2), (1, 6, 2, 2), (4, 33, 1, 2)])
def test_shape_contract(name: str, batch: int, length: int, d_in: int, d_out: int) -> None:
    block = make(name, d_in, d_out)
    y, state = block(random_input(batch, length, d_in))
    assert y.shape == (batch, length, d_out) and y.dtype == torch.float32
    assert torch.isfinite(y).all()
    y2, _ = block(random_input(batch, length, d_in), state)  # the returned state is accepted
    assert y2.shape == (batch, length, d_out)
    with pytest.raises(ValueError, match="expects input of shape"):
        block(random_input(batch, length, d_in + 1))


@pytest.mark.parametrize("name,hparams", VARIANTS)
def test_causal_perturbing_step_k_changes_only_steps_from_k(name: str, hparams: dict) -> None:
    block = make(name, d_in=2, d_out=2, dtype=torch.float64, **hparams)
    x = random_input(2, 40, 2, torch.float64)
    k = 17
    x_perturbed = x.clone()
    x_perturbed[:, k] += 1.0
    with torch.no_grad():
        y, _ = block(x)
        y_perturbed, _ = block(x_perturbed)
    assert torch.equal(y[:, :k], y_perturbed[:, :k]), "an output before step k saw input k"
    change = (y_perturbed - y)[:, k:].abs().amax(dim=(0, 2))  # (L - k,)
    if name == "transformer":  # banded: through n layers it reaches n (context - 1) steps on
        change = change[: len(block.layers) * (block.context - 1) + 1]
    assert (change > 1e-12).all(), f"outputs at steps >= k did not react: {change}"


SPLITS = [(40, [1, 39]), (40, [17, 23]), (40, [13, 1, 12, 14]), (300, [129, 1, 170]), (300, [300])]


@pytest.mark.parametrize("name,hparams", VARIANTS)
@pytest.mark.parametrize("dtype,tol", [(torch.float32, 2e-5), (torch.float64, 1e-11)])
def test_chunked_with_state_equals_whole(name: str, hparams: dict, dtype: torch.dtype,
                                         tol: float) -> None:
    block = make(name, d_in=3, d_out=2, dtype=dtype, **hparams)
    for length, chunks in SPLITS:
        x = random_input(2, length, 3, dtype)
        with torch.no_grad():
            whole, _ = block(x)
            state, parts = block.default_state(2, x.device, dtype), []
            for piece in x.split(chunks, dim=1):
                before = state
                y, state = block(piece, before)
                again, _ = block(piece, before)  # a state is an input, never modified in place
                assert torch.equal(y, again)
                parts.append(y)
        torch.testing.assert_close(torch.cat(parts, dim=1), whole, rtol=tol, atol=tol)


@pytest.mark.parametrize("name", NAMES)
def test_zero_init_outputs_exactly_zero_and_trains_the_head(name: str) -> None:
    block = make(name, d_in=2, d_out=2, zero_init=True)
    x = random_input(3, 25, 2)
    y, state = block(x)
    assert torch.equal(y, torch.zeros_like(y))
    y_next, _ = block(x, state)
    assert torch.equal(y_next, torch.zeros_like(y_next))
    ((y - torch.ones_like(y)) ** 2).mean().backward()
    assert block.head.weight.grad.abs().sum() > 0 and block.head.bias.grad.abs().sum() > 0


@pytest.mark.parametrize("name,hparams", VARIANTS)
def test_gradients_reach_every_parameter(name: str, hparams: dict) -> None:
    block = make(name, d_in=2, d_out=2, **hparams).train()
    y, _ = block(random_input(4, 40, 2))
    ((y - 0.5) ** 2).mean().backward()
    for pname, p in block.named_parameters():
        assert p.grad is not None, f"{pname} gets no gradient"
        assert torch.isfinite(p.grad).all(), f"{pname} has a non-finite gradient"
        assert p.grad.abs().sum() > 0, f"{pname} has a zero gradient"


def test_transformer_attends_to_a_band_of_context_steps() -> None:
    """Through n layers an input reaches outputs up to n (context - 1) steps later, no further."""
    context, n_layers = 5, 2
    block = make("transformer", d_in=1, d_out=1, dtype=torch.float64, context=context,
                 n_layers=n_layers)
    x = random_input(1, 30, 1, torch.float64)
    x_perturbed = x.clone()
    x_perturbed[:, 10] += 1.0
    with torch.no_grad():
        diff = (block(x_perturbed)[0] - block(x)[0])[0, :, 0].abs()  # (L,)
    reach = 10 + n_layers * (context - 1)
    assert (diff[10:reach + 1] > 0).all()
    assert torch.equal(diff[reach + 1:], torch.zeros_like(diff[reach + 1:]))


def test_transformer_long_record_is_processed_in_query_blocks() -> None:
    """L = 6000 runs in O(L · context) memory (an L×L float64 mask alone would be 288 MB)."""
    block = make("transformer", d_in=1, d_out=1, context=100)
    with torch.no_grad():
        y, cache = block(random_input(1, 6000, 1))
    assert y.shape == (1, 6000, 1) and all(k.shape[2] == 99 for k, _ in cache)


# -- the cores against their definitions -----------------------------------------------------
@pytest.mark.parametrize("max_decay", [None, 7.0])
def test_s4d_kernel_equals_its_zoh_recurrence(max_decay: float | None) -> None:
    """y_k = 2 Re(C x_k) + D u_k with x_k = Ā x_{k-1} + B̄ u_k, Ā = exp(ΔA), B̄ = (Ā - 1)/A,
    Re A = -exp(a_re_log) - 1/(τ_max Δ)."""
    torch.manual_seed(0)
    ssm = S4DKernel(d_model=3, d_state=8, init="inv", dt_min=0.01, dt_max=0.5,
                    max_decay=max_decay).double()
    u = torch.randn(2, 3, 150, dtype=torch.float64)  # longer than the direct path: FFT
    x0 = torch.randn(2, 3, 4, dtype=torch.complex128)
    y, x_last = ssm(u, x0)
    with torch.no_grad():
        dt = ssm.log_dt.exp()[:, None]
        floor = 0.0 if max_decay is None else 1 / (max_decay * dt)
        a = torch.complex(-ssm.a_re_log.exp() - floor, ssm.a_im)
        a_bar = torch.exp(dt * a)
        b_bar, c = (a_bar - 1) / a, torch.view_as_complex(ssm.c)
        x, ys = x0, []
        for k in range(u.shape[-1]):
            x = a_bar * x + b_bar * u[..., k, None]
            ys.append(2 * (c * x).sum(-1).real + ssm.d * u[..., k])
    torch.testing.assert_close(y, torch.stack(ys, dim=-1), rtol=1e-10, atol=1e-10)
    torch.testing.assert_close(x_last, x, rtol=1e-10, atol=1e-10)


# Raw parameters far outside what training starts from: a slow decay (Δ exp(a_re_log) -> 0,
# where plain S4D's |Ā| rounds to 1 in float32) and a fast one, tiny and huge steps.
ADVERSARIAL = [(-30.0, -30.0), (-30.0, 0.0), (0.0, -30.0), (-12.0, 0.0), (30.0, 30.0), (-30.0, 30.0),
               (30.0, -30.0)]  # (log_dt, a_re_log)


def _set_raw(block: torch.nn.Module, log_dt: float, a_re_log: float) -> None:
    with torch.no_grad():
        for ssm in (m for m in block.modules() if isinstance(m, S4DKernel)):
            ssm.log_dt.fill_(log_dt)
            ssm.a_re_log.fill_(a_re_log)


@pytest.mark.parametrize("log_dt,a_re_log", ADVERSARIAL)
def test_s4d_every_mode_decays_within_max_decay_for_any_parameters(log_dt: float,
                                                                  a_re_log: float) -> None:
    """The shipped S4 keeps |Ā| <= exp(-1/τ_max) < 1 in float32 whatever the raw parameters."""
    block = make("s4", d_in=2, d_out=1)
    _set_raw(block, log_dt, a_re_log)
    for ssm in (m for m in block.modules() if isinstance(m, S4DKernel)):
        with torch.no_grad():
            a_bar, b_bar = ssm.discrete()
        assert torch.isfinite(torch.view_as_real(a_bar)).all()
        assert torch.isfinite(torch.view_as_real(b_bar)).all()
        assert a_bar.abs().max() <= math.exp(-1 / 25.0) + 1e-6
    with torch.no_grad():
        assert torch.isfinite(block(random_input(1, 300, 2))[0]).all()


@pytest.mark.parametrize("log_dt,a_re_log", [(-3.0, -20.0), (0.0, -12.0), (-1.0, 0.0)])
def test_s4_long_free_run_depends_only_on_the_recent_past(log_dt: float, a_re_log: float) -> None:
    """A free run far longer than a training window meets only states a window reaches.

    The shipped S4 forgets within τ_max = 25 samples, so its output after 4000 steps equals the
    output of a fresh start 200 samples before (e^-8 of the old state left) and stays as large
    as in the first window, even with slow raw modes and an input with a mean (which plain
    S4D's slow modes integrate: they drift as a ramp all run long).
    """
    block = make("s4", d_in=1, d_out=1, dtype=torch.float64)
    _set_raw(block, log_dt, a_re_log)
    x = 1.0 + random_input(1, 4000, 1, torch.float64)
    with torch.no_grad():
        y, state = block(x)
        fresh, _ = block(x[:, -200:])
        drift = [s.abs().max().item() for s in state]
        start = [s.abs().max().item() for s in block(x[:, :200])[1]]
    torch.testing.assert_close(y[:, -10:], fresh[:, -10:], rtol=1e-3, atol=1e-3)
    assert y[:, 200:].abs().max() <= 2 * y[:, :200].abs().max()
    assert max(d / s for d, s in zip(drift, start)) < 2


def test_fft_and_direct_convolution_agree() -> None:
    length = 90
    u = torch.randn(2, 4, length, dtype=torch.float64)
    kernel = torch.randn(4, length, dtype=torch.float64)
    reference = torch.stack(
        [(kernel[:, : k + 1].flip(-1) * u[..., : k + 1]).sum(-1) for k in range(length)], dim=-1
    )
    fft = causal_convolution(u, kernel, direct_max_len=0)
    direct = causal_convolution(u, kernel, direct_max_len=length)
    torch.testing.assert_close(fft, reference)
    torch.testing.assert_close(direct, reference)


def _selective_scan_reference(u: torch.Tensor, delta: torch.Tensor, a: torch.Tensor,
                              b: torch.Tensor, c: torch.Tensor, d: torch.Tensor, h0: torch.Tensor,
                              min_rate: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
    """The definition, step by step (differentiated by autograd)."""
    h, ys = h0, []
    for k in range(u.shape[1]):
        drive = (delta[:, k] * u[:, k])[..., None] * b[:, k, None, :]
        h = torch.exp(delta[:, k, :, None] * a - min_rate) * h + drive
        ys.append((h * c[:, k, None, :]).sum(-1) + d * u[:, k])
    return torch.stack(ys, dim=1), h


@pytest.mark.parametrize("length,steps_per_block,min_rate", [(7, None, 0.0), (7, 1, 0.0), (7, 3, 0.0),
                                                         (1, None, 0.0), (7, 3, 0.3)])
def test_selective_scan_values_and_handwritten_gradients(length: int, steps_per_block: int | None,
                                                         min_rate: float) -> None:
    g = torch.Generator().manual_seed(3)
    batch, d_inner, n = 2, 3, 4
    args = [torch.randn(batch, length, d_inner, generator=g),
            torch.rand(batch, length, d_inner, generator=g),
            -torch.rand(d_inner, n, generator=g) - 0.1,
            torch.randn(batch, length, n, generator=g),
            torch.randn(batch, length, n, generator=g),
            torch.randn(d_inner, generator=g),
            torch.randn(batch, d_inner, n, generator=g)]
    args = [t.double().requires_grad_() for t in args]

    def scan(*inputs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return selective_scan(*inputs, steps_per_block=steps_per_block, min_rate=min_rate)

    y, h = scan(*args)
    y_ref, h_ref = _selective_scan_reference(*args, min_rate=min_rate)
    torch.testing.assert_close(y, y_ref)
    torch.testing.assert_close(h, h_ref)
    assert torch.autograd.gradcheck(scan, args)  # y and the final state, w.r.t. all inputs


@pytest.mark.parametrize("a_log,dt_bias", [(-20.0, -20.0), (-20.0, 0.0), (0.0, -20.0)])
def test_mamba_long_free_run_depends_only_on_the_recent_past(a_log: float, dt_bias: float) -> None:
    """The shipped Mamba forgets within max_decay = 25 samples whatever Δ and A learn: after 4000
    steps its output equals a fresh start 200 samples before and its states stay as large as
    in the first window (plain Mamba's slow states, Δ |A| -> 0, integrate an input's mean)."""
    block = make("mamba", d_in=1, d_out=1, dtype=torch.float64)
    with torch.no_grad():
        for layer in block.layers:
            layer.a_log.fill_(a_log)
            layer.dt_proj.bias.fill_(dt_bias)
    x = 1.0 + random_input(1, 4000, 1, torch.float64)
    with torch.no_grad():
        y, state = block(x)
        fresh, _ = block(x[:, -200:])
        drift = [s.abs().max().item() for _, s in state]
        start = [s.abs().max().item() for _, s in block(x[:, :200])[1]]
    torch.testing.assert_close(y[:, -10:], fresh[:, -10:], rtol=1e-3, atol=1e-3)
    assert max(d / s for d, s in zip(drift, start)) < 2
    with pytest.raises(ValueError, match="max_decay"):
        build_ann("mamba", 1, 1, max_decay=-1.0)


# -- the GRU -------------------------------------------------------------------------------------
def _gru_reference(block: GRUBlock, x: torch.Tensor, h0: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The equations of GRUBlock's docstring, step by step: r, z, n = the reset, update and new gates,
    n = tanh(W_n x + b_in + r ⊙ (U_n h + b_hn)), h' = (1 - z) ⊙ n + z ⊙ h, y = W_y h' + b_y."""
    inputs, last = block.proj(x), []
    for layer in range(block.num_layers):
        w_ih, w_hh = getattr(block.gru, f"weight_ih_l{layer}"), getattr(block.gru, f"weight_hh_l{layer}")
        b_ih, b_hh = getattr(block.gru, f"bias_ih_l{layer}"), getattr(block.gru, f"bias_hh_l{layer}")
        h, hs = h0[layer], []
        for k in range(x.shape[1]):
            wx_r, wx_z, wx_n = (inputs[:, k] @ w_ih.T + b_ih).chunk(3, dim=-1)
            uh_r, uh_z, uh_n = (h @ w_hh.T + b_hh).chunk(3, dim=-1)
            r, z = torch.sigmoid(wx_r + uh_r), torch.sigmoid(wx_z + uh_z)
            n = torch.tanh(wx_n + r * uh_n)
            h = (1 - z) * n + z * h
            hs.append(h)
        inputs = torch.stack(hs, dim=1)
        last.append(h)
    return block.head(inputs), torch.stack(last)


@pytest.mark.parametrize("hparams", [{"hidden_size": 5}, {"hidden_size": 4, "num_layers": 2, "input_proj": 3}])
def test_gru_follows_its_equations_with_a_plain_tensor_state(hparams: dict) -> None:
    block = make("gru", d_in=2, d_out=3, dtype=torch.float64, **hparams)
    x = random_input(2, 9, 2, torch.float64)
    h0 = 0.5 * torch.randn(block.num_layers, 2, block.hidden_size, dtype=torch.float64)
    with torch.no_grad():
        y, h = block(x, h0)
        y_ref, h_ref = _gru_reference(block, x, h0)
    torch.testing.assert_close(y, y_ref, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(h, h_ref, rtol=1e-12, atol=1e-12)
    assert isinstance(h, torch.Tensor) and h.shape == (block.num_layers, 2, block.hidden_size)
    default = block.default_state(2, None, torch.float64)
    assert torch.equal(default, torch.zeros_like(h)) and default.dtype == torch.float64


def test_gru_one_sample_steps_continue_a_state_exactly() -> None:
    """A record run one sample at a time (as an exported step runs it) from the state after a first
    chunk equals the whole run; and a state carries the past: from zeros the same steps differ."""
    block = make("gru", d_in=3, d_out=2, hidden_size=6, num_layers=2)
    with torch.no_grad():
        block.head.weight.mul_(10.0)  # outputs that show the state
        x = random_input(1, 60, 3)
        whole, h_end = block(x)
        _, state = block(x[:, :20])
        steps = []
        for k in range(20, 60):
            y, state = block(x[:, k:k + 1], state)
            steps.append(y)
        fresh, _ = block(x[:, 20:])
    torch.testing.assert_close(torch.cat(steps, dim=1), whole[:, 20:], rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(state, h_end, rtol=1e-5, atol=1e-6)
    assert (fresh[:, :3] - whole[:, 20:23]).abs().max() > 1e-3


@pytest.mark.parametrize("hparams, message", [({"hidden_size": 0}, "hidden_size and num_layers must be >= 1"),
                                              ({"num_layers": 0}, "hidden_size and num_layers must be >= 1"),
                                              ({"dropout": 1.0}, r"dropout must be in \[0, 1\)"),
                                              ({"dropout": -0.1}, r"dropout must be in \[0, 1\)"),
                                              ({"input_proj": 0}, "input_proj must be None or >= 1")])
def test_gru_rejects_bad_arguments_in_one_line(hparams: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message) as error:
        build_ann("gru", 2, 1, **hparams)
    assert "\n" not in str(error.value)
    with pytest.raises(ValueError, match="d_out must be a positive integer"):
        build_ann("gru", 2, 0)


def test_gru_trains_and_exports_exactly_through_the_command_line(tmp_path: Path, hypa_cache: Path) -> None:
    """hypa train model=v2 ann=gru (both networks GRUs), then hypa export format=c: its checks, the one-step model
    (each GRU's forward on one-sample chunks) and its C form (ONNX's GRU cell in loops) against hypa's free run,
    pass; the state holds one h per GRU."""
    run, out = tmp_path / "run", tmp_path / "export"
    trained = hypa_run(["train", "model=v2", "ann=gru", "ann.hidden_size=8", "trainer.max_epochs=1",
                        "trainer.limit_train_batches=2", "trainer.limit_val_batches=2",
                        "trainer.enable_progress_bar=false", "figures.enabled=false", "data.batch_size=8",
                        "identification.max_seconds=5", *SHORT_OVERRIDES, f"hydra.run.dir={run}"])
    assert trained.returncode == 0, trained.stderr[-3000:]
    ckpt = torch.load(run / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    assert ckpt["hyper_parameters"]["ann_name"] == "gru"
    assert ckpt["state_dict"]["model.blocks.correction.gru.weight_hh_l0"].shape == (3 * 8, 8)
    exported = hypa_run(["export", f"run={run}", "format=c", f"hydra.run.dir={out}"])  # the ONNX step and the C one
    assert exported.returncode == 0, exported.stderr[-3000:]
    description = json.loads((out / "export.json").read_text())
    assert description["check"]["passed"] and description["checks"]["c"]["passed"]
    assert description["onnx"]["inputs"]["state"] == [2 + 2 * 8]  # the single track's 2 states, two GRUs' h


# -- registry and configs --------------------------------------------------------------------
def test_build_ann_rejects_unknown_names_and_hyperparameters() -> None:
    with pytest.raises(ValueError, match=r"unknown ANN block 'rnn'.*gru.*lstm.*mamba.*s4.*transformer"):
        build_ann("rnn", 1, 1)
    with pytest.raises(TypeError, match=r"hidden_sise.*accepted: hidden_size"):
        build_ann("lstm", 1, 1, hidden_sise=32)
    with pytest.raises(ValueError, match="divisible"):
        build_ann("transformer", 1, 1, d_model=30, n_heads=4)
    with pytest.raises(ValueError, match="d_in"):
        build_ann("s4", 0, 1)
    with pytest.raises(ValueError, match="max_decay"):
        build_ann("s4", 1, 1, max_decay=0.0)


def test_every_block_has_a_config_with_its_defaults() -> None:
    assert sorted(p.stem for p in CONF_ANN.glob("*.yaml")) == NAMES
    with initialize_config_dir(config_dir=str(CONF_ANN.parent), version_base=None):
        for name in NAMES:
            cfg = OmegaConf.to_container(compose(overrides=[f"+ann={name}"]).ann)
            assert cfg.pop("name") == name
            assert cfg.pop("_target_") == target(name)  # the block instantiate builds
            defaults = ann_hyperparameters(name)
            defaults.pop("zero_init")
            cfg = {k: defaults.get(k) if v is None else v for k, v in cfg.items()}  # null: the block's (see hypa train)
            assert cfg == defaults, f"conf/ann/{name}.yaml differs from the code defaults"
            block = build_ann(name, 2, 1, **cfg)
            assert block(torch.zeros(1, 3, 2))[0].shape == (1, 3, 1)


# -- learning ------------------------------------------------------------------------------------
def _first_order_lag(batch: int, length: int, g: torch.Generator
                     ) -> tuple[torch.Tensor, torch.Tensor]:
    """Piecewise-constant input levels and y_k = 0.9 y_{k-1} + 0.1 x_k, scaled to unit size."""
    levels = torch.randn(batch, length // 8 + 1, 1, generator=g)
    x = levels.repeat_interleave(8, dim=1)[:, :length]  # (B, L, 1)
    y, ys = torch.zeros(batch, 1), []
    for k in range(length):
        y = 0.9 * y + 0.1 * x[:, k]
        ys.append(y)
    return x, torch.stack(ys, dim=1) / 0.6


@pytest.mark.parametrize("name", NAMES)
def test_learns_a_first_order_lag(name: str) -> None:
    g = torch.Generator().manual_seed(0)
    block = make(name, d_in=1, d_out=1).train()
    x_val, y_val = _first_order_lag(16, 48, g)

    def val_loss() -> float:
        with torch.no_grad():
            return torch.mean((block(x_val)[0] - y_val) ** 2).item()

    initial = val_loss()
    opt = torch.optim.Adam(block.parameters(), lr=3e-3)
    for _ in range(150):
        x, y = _first_order_lag(8, 48, g)
        loss = torch.mean((block(x)[0] - y) ** 2)
        opt.zero_grad()
        loss.backward()
        opt.step()
    final = val_loss()
    target_power = y_val.square().mean().item()
    assert math.isfinite(final) and final < 0.2 * initial, (initial, final)
    assert final < 0.1 * target_power, (final, target_power)
