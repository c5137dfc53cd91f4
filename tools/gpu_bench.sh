#!/usr/bin/env bash
# The benchmarks of issue 15 item 6 on a GPU, in one go (field, render, train, the padded MLP's
# same-run comparison and its crossover, then the CUDA tests), each bounded in time so that one
# failure leaves the others' numbers. About 6 minutes on an H200 (README, "On a GPU").
#
#   OUT=results/ DATA=path/to/bench_data tools/gpu_bench.sh    (from the repository root)
#
# OUT: where the JSON and the logs go; DATA: the training benchmark's dataset (default: synthesised
# by the benchmark); DEVICE (default cuda), POINTS (field batch, default 2^20), BUDGET_S (train
# benchmark's equal wall-clock budget, default 60), RESOLUTION (render, default 1024x667).
set -u
OUT=${OUT:?set OUT to a folder}
DEVICE=${DEVICE:-cuda}
POINTS=${POINTS:-1048576}
BUDGET_S=${BUDGET_S:-60}
RESOLUTION=${RESOLUTION:-1024x667}
WORK=${WORK:-/tmp/lisa_gpu_bench}
export PYTHONUNBUFFERED=1
mkdir -p "$OUT" "$WORK"
(nvidia-smi --query-gpu=name,memory.total,driver_version,clocks.sm --format=csv || true) \
    2>&1 | tee "$OUT/machine.log"
python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())" \
    2>&1 | tee -a "$OUT/machine.log"

timeout 150 python3 -m benchmarks field --device "$DEVICE" --points "$POINTS" --no-fused \
    --json "$OUT/field.json" 2>&1 | tee "$OUT/field.log"
timeout 120 python3 -m benchmarks render --device "$DEVICE" --resolution "$RESOLUTION" \
    --variants --json "$OUT/render.json" 2>&1 | tee "$OUT/render.log"
data_args=()
if [ -n "${DATA:-}" ]; then data_args=(--data "$DATA"); fi
timeout 300 python3 -m benchmarks train --device "$DEVICE" "${data_args[@]}" \
    --work "$WORK/train" --budget-s "$BUDGET_S" --json "$OUT/train.json" 2>&1 | tee "$OUT/train.log"
if [ -n "${DATA:-}" ]; then
    timeout 120 python3 -m tools.padded_rates "$DATA" --device "$DEVICE" 2>&1 \
        | tee "$OUT/padded_rates.log"
fi
if [ "$DEVICE" != cpu ]; then
    timeout 120 python3 -m tools.padded_crossover --device "$DEVICE" 2>&1 \
        | tee "$OUT/padded_crossover.log"
    timeout 120 python3 -m pytest -q -p no:cacheprovider -k "cuda" tests/model \
        tests/fitting/test_images.py tests/training tests/render tests/geometry \
        tests/data/test_images.py 2>&1 | tail -n 30 | tee "$OUT/tests.log"
fi
echo "summary:"
grep -h "^headline\|^backward (loss\|^fast (volume\|^steps per second\|over the loop" "$OUT"/*.log
