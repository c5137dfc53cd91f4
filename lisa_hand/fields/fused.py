"""Fused inference of a stacked MLP's row chunks: ``torch.compile`` of one chunk's layer chain.

In eager PyTorch every hidden layer of :meth:`lisa_hand.fields.mlp.StackedMLP.forward_grouped`
is two passes over memory, ``addmm`` then Softplus, and Softplus (``beta`` = 100) costs about as
much as the product: ``exp`` and ``log1p`` of every element at full (1 ulp) accuracy. Here one
chunk's whole chain is compiled with inductor (C++ on CPU): the bias and the activation become
one vectorised loop after each (MKL) product, and the Softplus is :func:`fast_softplus`, a
polynomial formulation made of multiply-adds that agrees with ``F.softplus`` to 1e-8 (below the
float32 rounding of ``F.softplus`` itself, 1.6e-8, for ``beta`` = 100).

This path is for evaluation without gradients only (rendering, meshing, the benchmark): a
compiled function has no double backward (the Eikonal loss), so whenever autograd records,
``forward_grouped`` runs eagerly, unchanged. It is off by default, because compiling costs
seconds per MLP shape (reported by :func:`fused_stats`); :func:`set_fused_inference` or the
:func:`fused_inference` context turns it on. Rows are a dynamic dimension (one compilation per
chain shape, dtype and bias layout, not per group size); chunks under :data:`MIN_FUSED_ROWS`
rows run eagerly. When compilation is unavailable (no C++ compiler, an unsupported platform)
or fails, a warning is issued once and everything runs eagerly from then on.
"""

from __future__ import annotations

import contextlib
import math
import time
import warnings
from collections.abc import Callable, Iterator

import torch

__all__ = [
    "MIN_FUSED_ROWS",
    "fast_softplus",
    "fused_chain",
    "fused_inference",
    "fused_inference_enabled",
    "fused_stats",
    "set_fused_inference",
]

# Chunks with fewer rows run eagerly: dynamo specialises sizes 0 and 1, and a tiny chunk gains
# nothing from fusion.
MIN_FUSED_ROWS = 16

# Least-squares (Chebyshev) fits on [0, 1] in float64 (numpy.polynomial.Chebyshev.fit, 400001
# points, converted to power series): 2^f, degree 5 (relative error 3e-7), and
# log1p(s) / s, degree 7 (log1p(s) = s q(s): exact relative behaviour as s -> 0).
_EXP2_COEFFS = (
    0.9999997694712945, 0.6931567789349212, 0.24013168317929606, 0.05587656915298522,
    0.008940577519864407, 0.001894378592885803,
)  # fmt: skip
_LOG1P_OVER_S_COEFFS = (
    0.9999995179393946, -0.4999635468983539, 0.3326523898710215, -0.24453321199802527,
    0.17659724898045437, -0.1067977906528625, 0.0436584715143055, -0.008466244361828341,
)  # fmt: skip


def _horner(coeffs: tuple[float, ...], values: torch.Tensor) -> torch.Tensor:
    """``sum_k coeffs[k] values^k``, elementwise."""
    acc = values * coeffs[-1] + coeffs[-2]
    for coeff in coeffs[-3::-1]:
        acc = acc * values + coeff
    return acc


def fast_softplus(values: torch.Tensor, beta: float) -> torch.Tensor:
    """``F.softplus(values, beta)`` from multiply-adds, for fusion by a compiler.

    ``softplus(x) = max(x, 0) + log1p(exp(-beta |x|)) / beta`` with
    ``s = exp(-beta |x|) = 2^t``, ``t = n + f`` (``n = floor(t)``, ``f`` in [0, 1)): ``2^f`` is a
    degree-5 polynomial, ``2^n`` is built in the float exponent bits, and ``log1p(s) = s q(s)``
    with ``q`` a degree-7 polynomial (``s`` in (0, 1]). Absolute error below 1e-8 for
    ``beta`` = 100 (``F.softplus`` in float32: 1.6e-8), relative error 2e-6 where the result is
    tiny. Float32 only (the exponent bits); slow eagerly (many passes), fast when compiled.

    values: [...] float32 -> [...]
    """
    if values.dtype != torch.float32:
        raise ValueError(f"fast_softplus needs float32 values, got {values.dtype}")
    exponent = torch.clamp(values.abs() * (-beta / math.log(2.0)), min=-126.0)  # log2(s)
    whole = torch.floor(exponent)
    power = ((whole.to(torch.int32) + 127) << 23).view(torch.float32)  # 2^n
    small = _horner(_EXP2_COEFFS, exponent - whole) * power  # s = exp(-beta |x|)
    return torch.relu(values) + small * _horner(_LOG1P_OVER_S_COEFFS, small) * (1.0 / beta)


_STATE: dict = {
    "enabled": False,
    "disabled_reason": None,
    "compile_seconds": 0.0,
    "compilations": 0,
    "fused_calls": 0,
    "eager_calls": 0,
}
_CHAINS: dict[tuple, Callable] = {}


def set_fused_inference(enabled: bool) -> None:
    """Turn the compiled inference path on or off for every :class:`StackedMLP`."""
    _STATE["enabled"] = bool(enabled)


def fused_inference_enabled() -> bool:
    """Whether the compiled inference path is on (and has not failed)."""
    return _STATE["enabled"] and _STATE["disabled_reason"] is None


@contextlib.contextmanager
def fused_inference(enabled: bool = True) -> Iterator[None]:
    """Run the block with the compiled inference path on (or off), then restore the setting."""
    previous = _STATE["enabled"]
    set_fused_inference(enabled)
    try:
        yield
    finally:
        set_fused_inference(previous)


def fused_stats() -> dict:
    """Counters of the compiled path: ``compile_seconds`` (wall time of the calls that
    compiled), ``compilations`` (graphs compiled), ``fused_calls``, ``eager_calls`` (chunks
    that fell back: too few rows) and ``disabled_reason`` (None unless compilation failed)."""
    return dict(_STATE)


def _chain_function(activation: str, beta: float) -> Callable:
    """One chunk through every layer: ``x -> act(x W_0 + b_0) -> ... -> h W_L + b_L``."""

    def act(values: torch.Tensor) -> torch.Tensor:
        if activation == "relu":
            return torch.relu(values)
        return fast_softplus(values, beta)

    def chain(rows, first_weight, first_bias, *params):
        hidden = act(rows @ first_weight + first_bias)
        for index in range(0, len(params) - 2, 2):
            hidden = act(hidden @ params[index] + params[index + 1])
        if params[-2].shape[1] == 1:  # one output: a dot product fused with the activation
            return (hidden * params[-2][:, 0]).sum(dim=-1, keepdim=True) + params[-1]
        return hidden @ params[-2] + params[-1]

    return chain


def _compiled_chain(key: tuple) -> Callable:
    chain = _CHAINS.get(key)
    if chain is None:
        chain = torch.compile(_chain_function(*key[:2]), dynamic=False)
        _CHAINS[key] = chain
    return chain


def _unique_graphs() -> int:
    from torch._dynamo.utils import counters

    return int(counters["stats"]["unique_graphs"])


def fused_chain(
    rows: torch.Tensor,
    first_weight: torch.Tensor,
    first_bias: torch.Tensor,
    layers: list[tuple[torch.Tensor, torch.Tensor]],
    activation: str,
    beta: float,
) -> torch.Tensor | None:
    """One chunk of one group through all layers, compiled; None where the caller must run it
    eagerly (path off or failed, gradients recorded, too few rows, not float32).

    rows: [R, in]; first_weight: [in, hidden]; first_bias: [hidden] or [R, hidden];
    layers: (weight [in, out], bias [out]) after the first layer, output last. -> [R, out]
    """
    if (
        not fused_inference_enabled()
        or torch.is_grad_enabled()
        or rows.dtype != torch.float32
        or rows.device.type != "cpu"
    ):
        return None
    if rows.shape[0] < MIN_FUSED_ROWS:
        _STATE["eager_calls"] += 1
        return None
    key = (activation, float(beta), len(layers), first_bias.dim())
    params = [tensor for pair in layers for tensor in pair]
    torch._dynamo.mark_dynamic(rows, 0)
    if first_bias.dim() == 2:
        torch._dynamo.mark_dynamic(first_bias, 0)
    graphs = _unique_graphs()
    start = time.perf_counter()
    try:
        out = _compiled_chain(key)(rows, first_weight, first_bias, *params)
    except Exception as error:  # noqa: BLE001 - any compiler failure means: run eagerly
        reason = f"{type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''}"
        _STATE["disabled_reason"] = reason
        warnings.warn(
            f"fused MLP inference unavailable, running eagerly ({reason})",
            RuntimeWarning,
            stacklevel=3,
        )
        return None
    if _unique_graphs() > graphs:
        _STATE["compile_seconds"] += time.perf_counter() - start
        _STATE["compilations"] += _unique_graphs() - graphs
    _STATE["fused_calls"] += 1
    return out
