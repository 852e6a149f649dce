#!/usr/bin/env bash
# The CUDA checks and measurements of edofproj in one go, on a machine with an NVIDIA GPU.
#
#   bash benchmarks/gpu/run_gpu_checks.sh [setup|placement|tests|suite|bench|shipped|live|compile|paper|loan|all]...   (default: all)
#
# setup      installs what the GPU image lacks from .whl/ (nothing can be fetched there; download
#            the wheels beforehand, see below) and makes the package importable without a build
#            (PYTHONPATH=src); stops the run when a package the checks import is missing
# placement  the fast tier of tests/test_device_placement.py, on the CPU (seconds): every component on
#            a second device (the meta device); a tensor made on the wrong device or in the wrong
#            dtype fails there, and the run stops before any GPU work (KEEP_GOING=1 goes on regardless)
# tests      the CUDA tests: test_cuda.py and every test parametrized with device=cuda (pytest -k cuda),
#            and a summary of them
# suite      the rest of the test suite (not part of `all`: CI runs it on the CPU)
# bench      `edofproj bench` on CUDA: FFT Wiener against the demo's network, the real-time network
#            and the paper's U-Net at 256x256, 600x800, 768x1024 (CUDA events, eager and CUDA graph)
# shipped    `edofproj bench --run REFERENCE_RUN` on CUDA: the method `live` and `compensate` ship (the
#            network behind its display guard) and its bare network against FFT Wiener, the three sizes;
#            benchmarks/guard_cost.py: the guard's stages at 600x800
# live       benchmarks/bench_live.py --device cuda: the live loop at 600x800 with an in-memory display
#            and an instant camera, the reference network (builtin:cpu-doe-net) and the real-time network
#            on the GPU: the network alone there, then every per-frame stage there (live --device cuda)
# compile    `edofproj bench --compile` on CUDA at COMPILE_SIZES (600x800): the reference model (guarded
#            and bare) and the real-time network, eager, compiled by torch.compile, and each as a CUDA graph
# paper      benchmarks/gpu/paper_scale.py: s/step and peak memory at the paper's sizes, fp32 vs bf16
# loan       benchmarks/gpu/loan.py: trains LOAN_CONFIG (the `paper` preset) until LOAN_S seconds after this
#            script started less a reserve, scores it (`edofproj evaluate`, test images and validation set),
#            and writes record.json, results.tar.gz and the run packed for the next loan (run.pack.json,
#            run.tar.NNN) into $OUT within what a loan brings back (8 files of 16 MB, 64 MB in all, counting
#            what the steps before wrote); LOAN_RESUME=FOLDER/run.pack.json continues a packed run
#            instead. Knobs: LOAN_S (540), LOAN_CONFIG (paper), LOAN_SET (space-separated KEY=VALUE
#            overrides), LOAN_RESUME, LOAN_DEVICE (cuda), LOAN_METHODS (doe+net), LOAN_SETS (test,validation; empty: none),
#            LOAN_ARGS (more options of loan.py)
#
# Knobs for a short loan (environment): BENCH_REPEATS (300), PAPER_STEPS (40), TESTS_TIMEOUT (420 s),
# STEP_TIMEOUT (the cap of bench, live and paper each, 600 s).
#
# setup and placement always run first. Results go to $OUT (default /tmp/edofproj-gpu): logs, CSV
# tables and results.tar.gz.
#
# Wheels the GPU image lacks (it has torch, numpy, scipy, scikit-image, OpenCV, matplotlib, tqdm,
# torchmetrics, PyYAML, markdown-it-py): trimesh (edofproj.training imports it through
# edofproj.scenes), rtree (scene ray casts), gdstk (fabrication). Before the loan, in the repository:
#   echo /.whl/ >> .git/info/exclude
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#       --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
#       -d .whl trimesh rtree gdstk
# and carry .whl with the working tree.
set -uo pipefail
cd "$(dirname "$0")/../.."
OUT=${OUT:-/tmp/edofproj-gpu}
WORK=${WORK:-/tmp/edofproj-gpu-work}
LOAN_S=${LOAN_S:-540}
LOAN_CONFIG=${LOAN_CONFIG:-paper}
LOAN_SET=${LOAN_SET:-}
LOAN_RESUME=${LOAN_RESUME:-}
LOAN_DEVICE=${LOAN_DEVICE:-cuda}
LOAN_METHODS=${LOAN_METHODS:-doe+net}
LOAN_SETS=${LOAN_SETS-test,validation}
LOAN_ARGS=${LOAN_ARGS:-}
REFERENCE_RUN=${REFERENCE_RUN:-builtin:cpu-doe-net}
BENCH_REPEATS=${BENCH_REPEATS:-300}
COMPILE_SIZES=${COMPILE_SIZES:-600x800}
PAPER_STEPS=${PAPER_STEPS:-40}
TESTS_TIMEOUT=${TESTS_TIMEOUT:-420}
STEP_TIMEOUT=${STEP_TIMEOUT:-600}
mkdir -p "$OUT" "$WORK"
export PYTHONUNBUFFERED=1 PYTHONPATH="$PWD/src:${PYTHONPATH:-}"
CLI="timeout $STEP_TIMEOUT python3 -m edofproj.cli"

setup() {
    if command -v nvidia-smi >/dev/null; then
        nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
    else
        echo "no nvidia-smi: no NVIDIA GPU here (only the CPU steps can run: loan with LOAN_DEVICE=cpu)"
    fi
    if compgen -G ".whl/*.whl" >/dev/null; then
        python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl || return 1
        export PYTHONPATH="$PYTHONPATH:/tmp/site"
    fi
    python3 - <<'PY' || return 1
import importlib.util, sys
needed = {"torch": "everything", "trimesh": "training (edofproj.training imports edofproj.scenes)"}
optional = {"rtree": "scene ray casts (evaluate --scene, tests/test_scenes_*)", "gdstk": "fabrication (tests/test_fab_*)"}
missing = {n: why for n, why in {**needed, **optional}.items() if importlib.util.find_spec(n) is None}
for name, why in missing.items():
    print(f"missing: {name} ({why}): put its wheel in .whl/ (see the header of this script)")
sys.exit(1 if set(missing) & set(needed) else 0)
PY
    python3 -c "import torch, edofproj; from edofproj.machine import instruction_sets; \
gpu = torch.cuda.get_device_name() if torch.cuda.is_available() else None; \
print('torch', torch.__version__, 'CUDA', torch.version.cuda, 'GPU', gpu, 'cuDNN', torch.backends.cudnn.version()); \
print('CPU', instruction_sets())"
}

placement() {
    python3 -m pytest tests/test_device_placement.py -m "not slow" -q -p no:cacheprovider 2>&1 \
        | tee "$OUT/placement.log" | tail -15
}

tests() {
    local xdist=""
    python3 -c "import xdist" 2>/dev/null && xdist="-n 8"
    timeout "$TESTS_TIMEOUT" python3 -m pytest tests -k cuda -q -rs $xdist -p no:cacheprovider --junitxml="$OUT/junit_cuda.xml" 2>&1 \
        | tee "$OUT/pytest_cuda.log" | tail -25
    python3 - "$OUT/junit_cuda.xml" <<'PY'
import sys, xml.etree.ElementTree as ET
cases = ET.parse(sys.argv[1]).getroot().iter("testcase")
gpu = {"passed": [], "failed": [], "skipped": []}
for case in cases:
    name = f"{case.get('classname')}::{case.get('name')}"
    state = "failed" if case.find("failure") is not None or case.find("error") is not None else \
        "skipped" if case.find("skipped") is not None else "passed"
    gpu[state].append(name)
print(f"CUDA tests: {len(gpu['passed'])} passed, {len(gpu['failed'])} failed, {len(gpu['skipped'])} skipped")
for state in ("failed", "skipped"):
    for name in gpu[state]:
        print(f"  {state}: {name}")
sys.exit(1 if gpu["failed"] or not gpu["passed"] else 0)
PY
}

suite() {
    local xdist=""
    python3 -c "import xdist" 2>/dev/null && xdist="-n 8"
    timeout 500 python3 -m pytest tests -k "not cuda" -q -rs $xdist -p no:cacheprovider 2>&1 | tee "$OUT/pytest.log" | tail -15
}

bench() {
    local common="--device cuda --repeats $BENCH_REPEATS --warmup 20 --no-onnx --methods wiener,unet --sizes 256x256,600x800,768x1024"
    local status=0
    $CLI bench $common --widths 16,32,64,128 --prefilter-bins 48 --csv "$OUT/bench_default.csv" \
        2>>"$OUT/bench.log" || status=1
    $CLI bench $common --widths 8,16 --architecture multirate --space-to-depth 4 --prefilter-bins 48 \
        --csv "$OUT/bench_realtime.csv" 2>>"$OUT/bench.log" || status=1
    $CLI bench $common --widths paper --csv "$OUT/bench_paper_unet.csv" 2>>"$OUT/bench.log" || status=1
    [ $status -eq 0 ] || tail -5 "$OUT/bench.log"
    return $status
}

shipped() {
    $CLI bench --device cuda --repeats "$BENCH_REPEATS" --warmup 20 --no-onnx --methods wiener,unet \
        --sizes 256x256,600x800,768x1024 --run "$REFERENCE_RUN" --csv "$OUT/bench_shipped.csv" 2>>"$OUT/bench.log" \
        || { tail -5 "$OUT/bench.log"; return 1; }
    timeout "$STEP_TIMEOUT" python3 benchmarks/guard_cost.py --device cuda --repeats 50 --run "$REFERENCE_RUN" 2>&1 \
        | grep -v Warning | tee "$OUT/guard_cost.log" | tail -10
}

live() {
    local status=0
    timeout "$STEP_TIMEOUT" python3 benchmarks/bench_live.py --device cuda --frames 300 --skip-virtual \
        --run builtin:cpu-doe-net 2>&1 | tee "$OUT/live_cpu_doe_net.log" | tail -30 || status=1
    timeout "$STEP_TIMEOUT" python3 benchmarks/bench_live.py --device cuda --frames 300 --skip-virtual \
        --config realtime 2>&1 | tee "$OUT/live_realtime.log" | tail -30 || status=1
    return $status
}

compile() {
    local common="--device cuda --repeats $BENCH_REPEATS --warmup 10 --no-onnx --methods unet --compile --sizes $COMPILE_SIZES"
    local status=0
    $CLI bench $common --run "$REFERENCE_RUN" --csv "$OUT/compile_reference.csv" 2>>"$OUT/compile.log" || status=1
    $CLI bench $common --widths 8,16 --architecture multirate --space-to-depth 4 --prefilter-bins 48 \
        --csv "$OUT/compile_realtime.csv" 2>>"$OUT/compile.log" || status=1
    [ $status -eq 0 ] || tail -5 "$OUT/compile.log"
    return $status
}

paper() {
    timeout "$STEP_TIMEOUT" python3 benchmarks/gpu/paper_scale.py --out "$WORK/paper_scale" --steps "$PAPER_STEPS" \
        --crop 1024 2>&1 | grep -v Warning | tee "$OUT/paper_scale.log" | tail -8
}

loan() {
    local sets=() s
    for s in $LOAN_SET; do sets+=(--set "$s"); done
    # shellcheck disable=SC2086  # LOAN_ARGS: options split as words
    python3 benchmarks/gpu/loan.py "$OUT" --budget-s "$((LOAN_S - SECONDS))" --config "$LOAN_CONFIG" \
        --device "$LOAN_DEVICE" --methods "$LOAN_METHODS" --sets "$LOAN_SETS" --work "$WORK/loan" \
        ${LOAN_RESUME:+--resume "$LOAN_RESUME"} "${sets[@]}" $LOAN_ARGS
}

steps=()
for step in "$@"; do
    case "$step" in
    all) steps+=(tests bench shipped live compile paper loan) ;;
    setup | placement) ;;  # always run first
    tests | suite | bench | shipped | live | compile | paper | loan) steps+=("$step") ;;
    *) echo "unknown step '$step' (setup, placement, tests, suite, bench, shipped, live, compile, paper, loan, all)" >&2; exit 2 ;;
    esac
done
[ $# -eq 0 ] && steps=(tests bench shipped live compile paper loan)
steps=(setup placement "${steps[@]}")
status=0
for step in "${steps[@]}"; do
    echo "=== $step ($(date +%T))"
    start=$SECONDS
    if ! "$step"; then
        echo "=== $step FAILED"
        status=1
        [ "$step" = setup ] && exit 1
        [ "$step" = placement ] && [ "${KEEP_GOING:-0}" != 1 ] && exit 1
    fi
    echo "=== $step took $((SECONDS - start)) s"
done
exit $status
