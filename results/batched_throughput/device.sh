#!/usr/bin/env bash
# The batched backend on a lent GPU machine (issue 71, point 5), ready to run so that its short
# time goes to measuring: first the CUDA equivalence check (tests/test_batched.py's GPU test:
# 20 updates of 2 runs, A3C FF and LSTM, on the GPU against the script's own CPU updates), then
# benchmarks/batched_throughput.py on cuda at N = 50, 64, 256 and 1024 runs against the process
# backend on every core (16 one-worker runs of agents/a3c_ff.py side by side). Everything it
# prints goes to OUT/device.log, the benchmark's report to OUT/cuda.txt, the machine to
# OUT/machine.txt; copy them here into results/batched_throughput/ and note the run in its
# COMMAND.txt.
#
#     results/batched_throughput/device.sh OUT [SECONDS]   (PYTHON: the interpreter)
#
# SECONDS: each batch's timed training (default 20). With SECONDS 10 it took 151 s on the H200
# (the check 16 s, the process backend 40 s, then each batch its SECONDS plus its building: N
# networks initialised on the CPU, 14 s at N = 1024; two warm-up updates and one evaluation).
#
# The machine lacks gymnasium and tyro (its torch, numpy, tensorboard, pytest and hypothesis
# do): make their wheels here, as results/campaign/COMMAND.txt says (`pip download ... -d .whl
# gymnasium==1.4.0 tyro==1.0.17 typeguard==4.6.1 typing_extensions==4.16.0
# docstring_parser==0.18.0 farama_notifications==0.0.6`, for the device's Python 3.12), carry
# ".whl", and run there, from the repository root:
#     python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
#         --target /tmp/site .whl/*.whl
#     export PYTHONPATH=/tmp/site:$PWD/agents:$PWD PYTHONUNBUFFERED=1 PYTHON=python3
#     bash results/batched_throughput/device.sh $OUT
set -uo pipefail
out=$1
seconds=${2:-20}
python=${PYTHON:-python3}
export SDL_VIDEODRIVER=dummy SDL_AUDIODRIVER=dummy MPLBACKEND=Agg
{
    nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv
    lscpu | grep -E "^(Model name|CPU\(s\)|Flags)" | cut -c1-200
    "$python" -c "import torch; print('torch', torch.__version__, torch.cuda.get_device_name())"
} > "$out/machine.txt" 2>&1
{
    echo "== the CUDA equivalence check"
    timeout 180 "$python" -m pytest -q -p no:cacheprovider tests/test_batched.py \
        -k "gpu or evaluation" -o addopts="" 2>&1 | tail -15
    echo "== benchmarks/batched_throughput.py --device cuda"
    timeout 480 "$python" benchmarks/batched_throughput.py --device cuda \
        --runs 50 64 256 1024 --seconds "$seconds" --out "$out/cuda.txt"
} 2>&1 | tee "$out/device.log"
