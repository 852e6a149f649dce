#!/usr/bin/env bash
# The CUDA checks and measurements of edofproj in one go, on a machine with an NVIDIA GPU.
#
#   bash benchmarks/gpu/run_gpu_checks.sh [setup|tests|bench|paper|scored|all]...   (default: all)
#
# setup   installs what the GPU image lacks (gdstk, from .whl/ when present, else from PyPI) and
#         makes the package importable without a build (PYTHONPATH=src)
# tests   the whole test suite; the CUDA cases (test_cuda.py, the `device`-parametrized tests,
#         the one-process NCCL run) run because a GPU is present
# bench   `edofproj bench` on CUDA: FFT Wiener against the demo's network, the real-time network
#         and the paper's U-Net at 256x256, 600x800, 768x1024 (CUDA events, eager and CUDA graph)
# paper   benchmarks/gpu/paper_scale.py: s/step and peak memory at the paper's sizes, fp32 vs bf16
# scored  trains the `paper` preset for SCORED_STEPS steps and evaluates it and the `cpu` preset's
#         run (REFERENCE_RUN, trained beforehand) on the same held-out images, on the GPU
#
# Results go to $OUT (default /tmp/edofproj-gpu): logs, CSV tables and results.tar.gz.
set -uo pipefail
cd "$(dirname "$0")/../.."
OUT=${OUT:-/tmp/edofproj-gpu}
WORK=${WORK:-/tmp/edofproj-gpu-work}
SCORED_STEPS=${SCORED_STEPS:-3000}
SCORED_CROP=${SCORED_CROP:-256}
SCORED_BATCH=${SCORED_BATCH:-4}
SCORED_PRECISION=${SCORED_PRECISION:-bf16}
REFERENCE_RUN=${REFERENCE_RUN:-runs/gpu_ref/cpu_doe_net}
mkdir -p "$OUT" "$WORK"
export PYTHONUNBUFFERED=1 PYTHONPATH="$PWD/src:${PYTHONPATH:-}"
CLI="python3 -m edofproj.cli"

setup() {
    nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
    if ! python3 -c "import gdstk" 2>/dev/null; then
        if compgen -G ".whl/*.whl" >/dev/null; then
            python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl || return 1
            export PYTHONPATH="$PYTHONPATH:/tmp/site"
        else
            python3 -m pip install -q gdstk || return 1
        fi
    fi
    python3 -c "import torch, edofproj, gdstk; print('torch', torch.__version__, 'CUDA', torch.version.cuda, \
'GPU', torch.cuda.get_device_name(), 'cuDNN', torch.backends.cudnn.version())"
}

tests() {
    local xdist=""
    python3 -c "import xdist" 2>/dev/null && xdist="-n 8"
    timeout 300 python3 -m pytest tests -q -rs $xdist -p no:cacheprovider --junitxml="$OUT/junit.xml" 2>&1 \
        | tee "$OUT/pytest.log" | tail -40
    python3 - "$OUT/junit.xml" <<'PY'
import sys, xml.etree.ElementTree as ET
cases = ET.parse(sys.argv[1]).getroot().iter("testcase")
gpu = {"passed": [], "failed": [], "skipped": []}
for case in cases:
    name = f"{case.get('classname')}::{case.get('name')}"
    if "test_cuda" not in name and "cuda" not in case.get("name"):
        continue
    state = "failed" if case.find("failure") is not None or case.find("error") is not None else \
        "skipped" if case.find("skipped") is not None else "passed"
    gpu[state].append(name)
print(f"CUDA tests: {len(gpu['passed'])} passed, {len(gpu['failed'])} failed, {len(gpu['skipped'])} skipped")
for state in ("failed", "skipped"):
    for name in gpu[state]:
        print(f"  {state}: {name}")
PY
}

bench() {
    local common="--device cuda --repeats 300 --warmup 20 --no-onnx --methods wiener,unet --sizes 256x256,600x800,768x1024"
    $CLI bench $common --widths 16,32,64,128 --prefilter-bins 48 --csv "$OUT/bench_default.csv" 2>/dev/null
    $CLI bench $common --widths 8,16 --architecture multirate --space-to-depth 4 --prefilter-bins 48 \
        --csv "$OUT/bench_realtime.csv" 2>/dev/null
    $CLI bench $common --widths paper --csv "$OUT/bench_paper_unet.csv" 2>/dev/null
}

paper() {
    timeout 200 python3 benchmarks/gpu/paper_scale.py --out "$WORK/paper_scale" --steps 40 --crop 1024 2>&1 \
        | grep -v Warning | tail -8
}

scored() {
    rm -rf "$WORK/paper_gpu"
    $CLI train --config paper --out "$WORK/paper_gpu" --quiet \
        --set data.source=builtin --set data.test_fraction=0.3 --set data.crop="$SCORED_CROP" \
        --set loss.perceptual=ms-ssim --set train.steps="$SCORED_STEPS" --set train.batch_size="$SCORED_BATCH" \
        --set train.checkpoint_every=1000 --set train.device=cuda --set train.mixed_precision="$SCORED_PRECISION" \
        || return 1
    local methods="lens,lens+wiener,doe,doe+wiener,doe+net"
    $CLI evaluate "$WORK/paper_gpu" --methods "$methods" --device cuda --out "$WORK/eval_paper" --quiet
    $CLI evaluate "$REFERENCE_RUN" --methods "$methods" --device cuda --out "$WORK/eval_cpu" --quiet
    cp "$WORK/paper_gpu/train_log.csv" "$OUT/paper_gpu_train_log.csv"
    tar -czf "$OUT/results.tar.gz" -C "$WORK" paper_gpu/config.yaml paper_gpu/doe.npz eval_paper/metrics.csv \
        eval_paper/tilted_metrics.csv eval_paper/summary.md eval_cpu/metrics.csv eval_cpu/tilted_metrics.csv \
        eval_cpu/summary.md 2>&1
}

steps=("$@")
[ ${#steps[@]} -eq 0 ] && steps=(all)
[ "${steps[0]}" = all ] && steps=(setup tests bench paper scored)
[ "${steps[0]}" != setup ] && steps=(setup "${steps[@]}")
status=0
for step in "${steps[@]}"; do
    echo "=== $step ($(date +%T))"
    start=$SECONDS
    "$step" || { echo "=== $step FAILED"; status=1; [ "$step" = setup ] && exit 1; }
    echo "=== $step took $((SECONDS - start)) s"
done
exit $status
