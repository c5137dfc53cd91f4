"""Part of the field benchmark (``python -m benchmarks field``): the ways of running the
stacked SDF MLP on the culled (point, bone) pairs, timed on the same pairs.

* ``sorted_loop_chunked``: the pairs sorted by bone, a loop over the bones in row chunks (what
  the model does, :meth:`lisa_hand.fields.mlp.StackedMLP.forward_grouped`);
* ``sorted_loop_unchunked``: the same without chunks;
* ``grouped_mm``: ``torch.nn.functional.grouped_mm`` on the sorted pairs;
* ``padded_bmm``: the pairs padded to ``[J, max rows, C]`` and one ``baddbmm`` a layer;
* ``index_select_scatter``: per bone, ``index_select`` of its points and ``index_copy`` back;
* ``sorted_loop_fused``: the sorted loop with the compiled fused chunk chains
  (:mod:`lisa_hand.fields.fused`; eager where compilation is unavailable);
* with ``compile_mlp``: the sorted loop through a ``torch.compile``'d chunk MLP with the stock
  Softplus (what the compiler alone gives).

The leading underscore keeps this module out of :func:`benchmarks.benchmark_names`.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import torch
import torch.nn.functional as F

from lisa_hand.fields.encoding import positional_encoding
from lisa_hand.fields.fused import fused_inference
from lisa_hand.model.lisa import FrameState, LisaModel
from lisa_hand.skeleton import NUM_JOINTS

from ._timing import interleaved_best, mlp_flops

__all__ = ["PairStrategies", "time_pair_strategies"]


class PairStrategies:
    """The culled pairs of one frame's query and one method per way of running the SDF MLP on
    them (each returns the MLP's outputs; run under ``torch.no_grad()``)."""

    def __init__(self, model: LisaModel, state: FrameState, points: torch.Tensor) -> None:
        """model, state: the field and its frame; points: [1, N, 3] world metres."""
        self.mlp = model.sdf_mlp
        self.pe_frequencies = model.config.pe_frequencies
        with torch.no_grad():
            self.local = model.bone_local_points(state, points)
            active = model.region_excess(state, points) < 0
        self.flat = active.reshape(-1, NUM_JOINTS)  # [N, J] point in bone's region
        self.bias = state.sdf_bias[0]  # [J, H]
        self.layers = self.mlp.layers()
        # grouped_mm needs row strides that are multiples of 16 bytes: pad the encoding to 40.
        mlp, layers = self.mlp, self.layers
        self.pad = (-mlp.point_dim) % 4
        self.padded_first = F.pad(mlp.point_weight, (0, 0, 0, self.pad))
        out_pad = (-mlp.out_dim) % 4
        self.padded_layers = layers[:-1] + [
            (F.pad(layers[-1][0], (0, out_pad)), F.pad(layers[-1][1], (0, out_pad)))
        ]
        self.compiled = None

    @property
    def num_pairs(self) -> int:
        return int(self.flat.sum())

    def run_rows(self, x: torch.Tensor, j: int) -> torch.Tensor:
        """Bone ``j``'s MLP on the encoded rows ``x``."""
        mlp, bias, layers = self.mlp, self.bias, self.layers
        hidden = mlp.act(torch.addmm(bias[j], x, mlp.point_weight[j]))
        for index, (weight, layer_bias) in enumerate(layers):
            hidden = torch.addmm(layer_bias[j], hidden, weight[j])
            if index < len(layers) - 1:
                hidden = mlp.act(hidden)
        return hidden

    def sorted_pairs(self) -> tuple[torch.Tensor, list[int]]:
        """The encoded pairs sorted by bone, and the number of pairs of each bone."""
        bone, point = self.flat.t().nonzero(as_tuple=True)
        sizes = self.flat.sum(0).tolist()
        enc = positional_encoding(
            self.local.reshape(-1, 3)[point * NUM_JOINTS + bone], self.pe_frequencies
        )
        return enc, sizes

    def loop_chunked(self) -> torch.Tensor:
        enc, sizes = self.sorted_pairs()
        return self.mlp.forward_grouped(enc, sizes, self.bias)

    def loop_fused(self) -> torch.Tensor:
        with fused_inference(True):
            return self.loop_chunked()

    def loop_unchunked(self) -> torch.Tensor:
        enc, sizes = self.sorted_pairs()
        return self.mlp.forward_grouped(enc, sizes, self.bias, chunk_rows=1 << 30)

    def grouped_mm(self) -> torch.Tensor:
        mlp, bias = self.mlp, self.bias
        enc, sizes = self.sorted_pairs()
        enc = F.pad(enc, (0, self.pad))
        counts = torch.tensor(sizes, device=enc.device)
        offsets = counts.cumsum(0).to(torch.int32)
        group = torch.repeat_interleave(torch.arange(NUM_JOINTS, device=enc.device), counts)
        hidden = mlp.act(F.grouped_mm(enc, self.padded_first, offs=offsets) + bias[group])
        for index, (weight, layer_bias) in enumerate(self.padded_layers):
            hidden = F.grouped_mm(hidden, weight, offs=offsets) + layer_bias[group]
            if index < len(self.layers) - 1:
                hidden = mlp.act(hidden)
        return hidden[:, : mlp.out_dim]

    def padded_bmm(self) -> torch.Tensor:
        mlp, bias, layers = self.mlp, self.bias, self.layers
        enc, sizes = self.sorted_pairs()
        device = enc.device
        group = torch.repeat_interleave(torch.arange(NUM_JOINTS, device=device),
                                        torch.tensor(sizes, device=device))
        starts = torch.tensor([0] + sizes[:-1], device=device).cumsum(0)
        slot = torch.arange(enc.shape[0], device=device) - starts[group]
        padded = enc.new_zeros(NUM_JOINTS, max(sizes), enc.shape[1])
        padded[group, slot] = enc
        hidden = mlp.act(torch.baddbmm(bias[:, None], padded, mlp.point_weight))
        for index, (weight, layer_bias) in enumerate(layers):
            hidden = torch.baddbmm(layer_bias[:, None], hidden, weight)
            if index < len(layers) - 1:
                hidden = mlp.act(hidden)
        return hidden[group, slot]

    def index_select_scatter(self) -> torch.Tensor:
        flat = self.flat
        out = self.local.new_zeros(flat.shape[0], NUM_JOINTS)
        local_flat = self.local.reshape(-1, NUM_JOINTS, 3)
        for j in range(NUM_JOINTS):
            rows = flat[:, j].nonzero()[:, 0]
            enc = positional_encoding(local_flat[rows, j], self.pe_frequencies)
            out[:, j].index_copy_(0, rows, self.run_rows(enc, j)[:, 0])
        return out

    def compile(self) -> None:
        """torch.compile (inductor, C++ codegen) of one chunk through all layers, dynamic rows
        (compiled at the first :meth:`loop_compiled`)."""
        mlp = self.mlp

        def run_chunk(x, first_weight, first_bias, *params):
            hidden = mlp.act(torch.addmm(first_bias, x, first_weight))
            for index in range(0, len(params), 2):
                hidden = torch.addmm(params[index + 1], hidden, params[index])
                if index < len(params) - 2:
                    hidden = mlp.act(hidden)
            return hidden

        self.compiled = torch.compile(run_chunk, dynamic=True)

    def loop_compiled(self) -> torch.Tensor:
        enc, sizes = self.sorted_pairs()
        outputs, start = [], 0
        for j, size in enumerate(sizes):
            for lo in range(start, start + size, 4096):
                hi = min(lo + 4096, start + size)
                params = [t for w, b in self.layers for t in (w[j], b[j])]
                outputs.append(self.compiled(enc[lo:hi], self.mlp.point_weight[j], self.bias[j],
                                             *params))
            start += size
        return torch.cat(outputs)


def time_pair_strategies(
    model: LisaModel,
    state: FrameState,
    points: torch.Tensor,
    repeats: int,
    log: Callable[[str], None],
    compile_mlp: bool = False,
    fused: bool = True,
) -> dict:
    """Time the ways of running the stacked SDF MLP on the culled (point, bone) pairs.

    -> {strategy: {"ms", "gflops"}, or {"error"} for a way this device does not run} (and
    ``compile_seconds`` with ``compile_mlp``).
    """
    pairs_run = PairStrategies(model, state, points)
    compile_seconds = None
    if compile_mlp:
        pairs_run.compile()
        with torch.no_grad():
            begin = time.perf_counter()
            pairs_run.loop_compiled()
            compile_seconds = time.perf_counter() - begin
        log(f"torch.compile of the chunk MLP: first call (compilation) {compile_seconds:.1f} s")
    strategies = {
        "sorted_loop_chunked": pairs_run.loop_chunked,
        "sorted_loop_unchunked": pairs_run.loop_unchunked,
        **({"sorted_loop_fused": pairs_run.loop_fused} if fused else {}),
        "grouped_mm": pairs_run.grouped_mm,
        "padded_bmm": pairs_run.padded_bmm,
        "index_select_scatter": pairs_run.index_select_scatter,
    }
    if compile_mlp:
        strategies["sorted_loop_compiled"] = pairs_run.loop_compiled
    pairs = pairs_run.num_pairs
    flops = mlp_flops(pairs_run.mlp, pairs, False)
    timings: dict = {}
    with torch.no_grad():
        for name, method in list(strategies.items()):
            try:  # some ways do not exist on every device (grouped_mm in float32 on a GPU)
                method()
            except (RuntimeError, NotImplementedError) as exc:
                reason = str(exc).strip().splitlines()[0] if str(exc).strip() else repr(exc)
                timings[name] = {"error": reason}
                del strategies[name]
        best = interleaved_best(strategies, repeats)
    log(f"SDF MLP on the {pairs} culled (point, bone) pairs, float32:")
    for name, failure in timings.items():
        log(f"  {name:22s}: unavailable here ({failure['error']})")
    for name, seconds in best.items():
        timings[name] = {"ms": seconds * 1e3, "gflops": flops / seconds / 1e9}
        log(f"  {name:22s}: {seconds * 1e3:8.1f} ms ({flops / seconds / 1e9:5.1f} GFLOP/s)")
    if compile_seconds is not None:
        timings["compile_seconds"] = compile_seconds
    return timings
