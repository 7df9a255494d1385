#!/usr/bin/env bash
# One lent-device session as one command (a start costs minutes of the 15): device.sh's check and
# benchmark (issue 71, point 5), then, if the measured rate says it fits in what is left of the
# command's CAP seconds, the confirmatory study's leg of LINE=RUNS (device_leg.sh). A batch's runs
# step together, so the leg's time is about its steps over the batch's steps/s whatever its N:
# STEPS / steps_s(N=50) + 21 evaluations, times 1.3, plus 60 s to build and check the plan.
# The leg's files come back as one archive, OUT/leg.tgz (the device returns at most 8 files, two
# folders down); unpack it here and follow device_leg.sh's header.
#
#     results/batched_throughput/device_session.sh OUT CAP SECONDS LINE=RUNS
#
# Run from the repository root on the device, with .whl carried (device.sh's header).
set -uo pipefail
out=$1
cap=$2
seconds=$3
leg=$4
begin=$(date +%s)
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD/agents:$PWD PYTHONUNBUFFERED=1 PYTHON=python3
bash results/batched_throughput/device.sh "$out" "$seconds"
left=$((cap - ($(date +%s) - begin)))
# the leg's projected seconds from the N=50 line of the benchmark's report
need=$(python3 - "$out/cuda.txt" <<'PY'
import re, sys
text = open(sys.argv[1]).read()
m = re.search(r"batched N=50[^:]*: ([\d,]+) run-steps/s.*?one evaluation \(N x 50 episodes\) ([\d.]+) s", text)
if not m:
    print(10**9)
else:
    steps_s = float(m.group(1).replace(",", "")) / 50
    print(int(1.3 * (250_000 / steps_s + 21 * float(m.group(2))) + 60))
PY
)
echo "== the leg $leg: about ${need}s needed, ${left}s left" | tee -a "$out/device.log"
if [ "$need" -lt "$left" ]; then
    mkdir -p /tmp/leg
    bash results/confirmatory/device_leg.sh /tmp/leg $((left - 15)) "$leg" 2>&1 | tee "$out/leg.log"
    tar czf "$out/leg.tgz" -C /tmp/leg .
else
    echo "the leg does not fit: skipped" | tee -a "$out/device.log"
fi
