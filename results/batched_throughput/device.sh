#!/usr/bin/env bash
# The batched backend on a lent GPU machine (issues 71 and 102), ready to run so that its short
# time goes to measuring: first the CUDA equivalence check (tests/test_batched.py's GPU tests:
# 20 updates of 2 runs, A3C FF, LSTM and LWS, on the GPU against the script's own CPU updates,
# the stacked convolutions as matmuls and as grouped convolutions), then
# benchmarks/batched_throughput.py on cuda at N = 50, 64, 256 and 1024 runs, each N with both
# convolution forms in turn (the run-steps/s, the ms of an update, a 50 x 1M line's projected
# minutes), against the process backend on every core (16 one-worker runs of agents/a3c_ff.py
# side by side). Everything it prints goes to OUT/device.log, the benchmark's report to
# OUT/cuda.txt, the machine to OUT/machine.txt; copy them here into results/batched_throughput/
# and note the run in its COMMAND.txt.
#
#     results/batched_throughput/device.sh OUT [SECONDS]   (PYTHON: the interpreter)
#
# SECONDS: each batch's timed training (default 10). Estimated at SECONDS 10 (from the H200's
# 151 s for one form): the check about 60 s, the process backend 40 s, then 8 batches of
# SECONDS plus their building (N networks initialised on the CPU, 14 s at N = 1024), two
# warm-up updates and 8 runs' evaluations: about 5 minutes in all, under the 8 of issue 102.
#
# The machine lacks gymnasium, tyro, pydantic and safetensors (its torch, numpy, tensorboard,
# pytest and hypothesis do): make their wheels here for the device's Python 3.12, before the
# device is started,
#     pip download --only-binary=:all: --python-version 3.12 --platform manylinux2014_x86_64 \
#         --platform manylinux_2_17_x86_64 --platform any -d .whl gymnasium tyro pydantic \
#         safetensors && rm .whl/numpy-*.whl   # (the device's own numpy stays)
# carry ".whl", and run there, from the repository root:
#     python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
#         --target /tmp/site .whl/*.whl
#     export PYTHONPATH=/tmp/site:$PWD/agents:$PWD PYTHONUNBUFFERED=1 PYTHON=python3
#     bash results/batched_throughput/device.sh $OUT
set -uo pipefail
out=$1
seconds=${2:-10}
python=${PYTHON:-python3}
export SDL_VIDEODRIVER=dummy SDL_AUDIODRIVER=dummy MPLBACKEND=Agg
{
    nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv
    lscpu | grep -E "^(Model name|CPU\(s\)|Flags)" | cut -c1-200
    "$python" -c "import torch; print('torch', torch.__version__, torch.cuda.get_device_name())"
} > "$out/machine.txt" 2>&1
{
    echo "== the CUDA equivalence check"
    timeout 120 "$python" -m pytest -q -p no:cacheprovider tests/test_batched.py \
        tests/test_stacked_convs.py -k "gpu or evaluation or stacked" -o addopts="" 2>&1 |
        tail -15
    echo "== benchmarks/batched_throughput.py --device cuda"
    timeout 330 "$python" benchmarks/batched_throughput.py --device cuda \
        --runs 50 64 256 1024 --conv-form grouped matmul --seconds "$seconds" \
        --out "$out/cuda.txt"
} 2>&1 | tee "$out/device.log"
