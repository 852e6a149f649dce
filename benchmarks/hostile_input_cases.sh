#!/usr/bin/env bash
# Hostile inputs of issue 29 (items 8-14) through the CLI, each printing its last line and exit code.
# Usage: bash benchmarks/hostile_input_cases.sh WORKDIR   (run it with PYTHONPATH=<tree>/src to try another tree)
# docs/experiments/2026-11-25-hostile-inputs.md records its output before and after the fixes.
set -u
work=${1:?give a work directory}
mkdir -p "$work" && cd "$work" || exit 1
E="${PYTHON:-python} -m edofproj.cli"
run() { echo "\$ edofproj $*"; timeout 60 nice $E "$@" 2>&1 | grep -v "warning" | tail -1 | cut -c1-240; echo "  exit ${PIPESTATUS[0]}"; }
rm -rf pat cap pat2 cap2 p3 c3 ev1 ev2 fab x tb tp dupout ft
$E procams patterns --width 128 --height 96 --out pat --dots 6x8 --color-levels 3 >/dev/null
$E procams simulate --patterns pat --out cap --depth-mm 350 --doe lens --window 21 --seed 1 >/dev/null 2>&1
$E procams calibrate --patterns pat --captures cap --out calib.npz >/dev/null 2>&1
head -c 20000 calib.npz > c.npz
${PYTHON:-python} - <<'PY'
import json, os
import numpy as np
d = dict(np.load("calib.npz")); d["neighbours"] = np.array(1e9); np.savez("n.npz", **d)
d = dict(np.load("calib.npz")); d["mixing_matrix"] = np.ones((3, 3)); np.savez("m.npz", **d)
import shutil; shutil.copytree("pat", "pat2")
m = json.load(open("pat2/manifest.json")); m["files"][0]["file"] = "../x/escaped.png"; json.dump(m, open("pat2/manifest.json", "w"))
os.makedirs("ev1"); os.makedirs("ev2")
rows = "method,depth_mm,image,psnr,ssim,ms_ssim\n" + "".join(f"{m},{z},a.png,30,0.9,0.95\n" for m in ("doe+net", "doe") for z in (300, 500))
open("ev1/metrics.csv", "w").write(rows); open("ev2/metrics.csv", "w").write(rows.replace(",500,", ",600,"))
import edofproj.builtin_runs as b
d = dict(np.load(b.ROOT / "cpu-doe-net" / "doe.npz")); d["aperture_radius_m"] = np.array(10e-3); np.savez("ap.npz", **d)
PY
printf "train:\n  steps: 2\n  steps: 3\n" > dup.yaml
run procams rectify cap/dots.png --calib c.npz --out r.png
run procams rectify cap/dots.png --calib n.npz --out r.png
run procams rectify cap/dots.png --calib m.npz --out r.png
run procams capture --patterns pat2 --out cap2 --display memory --camera "cmd:cp pat/red.png {out}"
run procams patterns --width 32 --height 32 --dots 2x2 --color-levels 2 --bernoulli 1 --out p3
run procams capture --patterns p3 --out c3 --display memory --camera "cmd:cp p3/white.png {out}"
run procams patterns --width 32 --height 32 --dots 2x2 --color-levels 2 --bernoulli 1 --seed 7 --out p3 --overwrite
run procams capture --patterns p3 --out c3 --display memory --camera "cmd:cp p3/white.png {out}"
run train --config cpu --set train.batch_size=100000000 --steps 1 --out tb
echo "  left in tb: $(ls tb 2>/dev/null | tr '\n' ' ')"
run train --config cpu --steps 1 --set psf.pupil_samples=256 --set train.batch_size=1 --set data.crop=32 --out tp
echo "  left in tp: $(ls tp 2>/dev/null | tr '\n' ' ')"
run bench --sizes 100000x100000
run finetune builtin:cpu-doe-net --psfs none.npz --lr nan --out ft
run train --config dup.yaml --steps 1 --out dupout
run summarize ev1 ev2
run summarize ev1 --reference nosuch
run export-doe ap.npz --out fab
