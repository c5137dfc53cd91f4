"""The field benchmark's plumbing on a small query: every step against the reference within the
tolerances, the training steps, the MLP share, the compilation's amortisation."""

from __future__ import annotations

import math
import time

import pytest
import torch

from lisa_hand.bench._pairs import PairStrategies, time_pair_strategies
from lisa_hand.bench._timing import large_matmul, mlp_share, timed_methods
from lisa_hand.bench.field import (
    SDF_TOLERANCE_M,
    _amortisation,
    _bench_hand,
    run_field_benchmark,
)
from lisa_hand.fields import FieldConfig
from lisa_hand.utils.threads import cpu_threads


def test_small_run_reports_forward_and_backward():
    lines: list[str] = []
    with cpu_threads(1):
        result = run_field_benchmark(1024, repeats=1, fused=False, log=lines.append)
    values = result.to_dict()
    steps = values["steps"]
    assert "culled_fused" not in steps and set(values["mlp_share"]) == {"culled"}
    for name in ("stacked", "culled", "culled_mixed"):
        assert steps[name]["within_tolerance"], name
        assert steps[name]["max_abs_error"]["sdf_m"] <= SDF_TOLERANCE_M
    assert not steps["culled_bf16"]["within_tolerance"]  # bfloat16 moves the SDF by ~1 mm
    assert values["headline_step"] in steps and 0 < values["mlp_share"]["culled"] < 1
    train = values["backward"]
    for name in ("forward", "backward", "eikonal"):
        assert train[name]["ms"] > 0 and train[name]["gflops_nominal"] > 0
    # A backward does more work than its forward, a double backward more still.
    assert train["eikonal"]["ms"] > train["backward"]["ms"] > train["forward"]["ms"]
    assert values["backward_gflops"] == train["backward"]["gflops_nominal"]
    assert train["matmul_gflops"] > 0 and "x 6" in train["flop_model"]
    assert any(line.startswith("backward (loss of the SDF") for line in lines)
    assert values["device"] == "cpu" and values["matmul"] == "2048^3"
    assert all(steps[name]["region_ties"] == 0 for name in steps)  # none in 1024 points


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the error without CUDA")
def test_cuda_without_cuda_is_one_clear_error():
    with pytest.raises(ValueError, match="CUDA is not available"):
        run_field_benchmark(64, repeats=1, fused=False, backward=False, device="cuda",
                            log=lambda line: None)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_run_matches_the_reference():
    result = run_field_benchmark(4096, repeats=1, fused=False, device="cuda",
                                 log=lambda line: None).to_dict()
    assert result["device"].startswith("cuda") and result["matmul"] == "8192^3"
    for name in ("stacked", "culled"):
        assert result["steps"][name]["within_tolerance"], name
    assert result["backward"]["eikonal"]["ms"] > 0


def test_a_pair_strategy_this_device_lacks_is_reported_not_fatal(monkeypatch):
    def unavailable(self):
        raise RuntimeError("grouped_mm: float32 is not supported here\nmore detail")

    monkeypatch.setattr(PairStrategies, "grouped_mm", unavailable)
    hand = _bench_hand(FieldConfig(), 512, 0)
    lines: list[str] = []
    with cpu_threads(1):
        timings = time_pair_strategies(hand.model, hand.state, hand.points, 1, lines.append,
                                       fused=False)
    assert timings["grouped_mm"] == {"error": "grouped_mm: float32 is not supported here"}
    assert timings["sorted_loop_chunked"]["ms"] > 0
    assert any("grouped_mm" in line and "unavailable here" in line for line in lines)


def test_amortisation():
    compilation = {"first_calls_s": 10.3, "compile_s": 9.0}
    best = {"culled": 0.2, "culled_fused": 0.15, "culled_fused_color": 0.15}
    _amortisation(compilation, best, lambda line: None)
    assert compilation["first_calls_extra_s"] == pytest.approx(10.0)
    assert compilation["saved_per_call_s"] == pytest.approx(0.05)
    assert compilation["break_even_calls"] == 200
    best["culled_fused"] = 0.25  # slower: never pays off
    _amortisation(compilation, best, lambda line: None)
    assert compilation["break_even_calls"] is None


class _Sleeper:
    def forward_grouped(self, seconds: float) -> float:
        time.sleep(seconds)
        return seconds


def test_timed_methods_and_mlp_share():
    sleeper = _Sleeper()
    totals: dict[str, float] = {}
    with timed_methods([sleeper], "forward_grouped", totals):
        assert sleeper.forward_grouped(0.01) == 0.01
    assert "forward_grouped" not in vars(sleeper)  # the wrapper is gone
    assert 0.01 <= totals["forward_grouped"] < 0.5

    def run():
        sleeper.forward_grouped(0.03)
        time.sleep(0.01)

    share = mlp_share(run, [sleeper], rounds=2)
    assert 0.5 < share < 0.9 and not math.isnan(share)
    assert torch.is_grad_enabled()


def test_large_matmul_is_the_product_it_counts():
    run, flops, name = large_matmul(torch.device("cpu"))
    product = run()
    assert name == "2048^3" and flops == 2.0 * 2048**3 and product.shape == (2048, 2048)
    assert float(product.std()) == pytest.approx(2048**0.5, rel=0.05)  # unit-normal entries
