#!/usr/bin/env bash
# The GPU checks of #38, on a machine with a CUDA GPU and python3 with torch (no ROS):
# `aslip train --stage scratch` on HOURS hours of synthetic 16 kHz audio (learn.synthetic,
# 60 s trials), EPOCHS epochs each, features cached once and shared:
#   - on the CPU, one process on every core;
#   - on the GPU, one process;
#   - on the GPU through torchrun (one rank: NCCL, DistributedDataParallel);
#   - on the CPU through torchrun with 2 ranks (gloo), half the cores each.
# Seconds per epoch and validation figures of each go to $OUT/gpu_scale.json.
#
#   OUT=results/gpu_scale HOURS=1 EPOCHS=3 bash benchmarks/gpu_scale.sh
set -euo pipefail
OUT=${OUT:-results/gpu_scale}
HOURS=${HOURS:-1}
EPOCHS=${EPOCHS:-3}
WORK=${WORK:-/tmp/gpu_scale}
mkdir -p "$OUT" "$WORK"
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
PY=${PY:-python3}
CORES=$(nproc)
"$PY" - <<EOF
import time
from aslip_ros.learn.synthetic import make_synthetic_dataset
t = time.perf_counter()
make_synthetic_dataset("$WORK/ds", n_trials=max(6, round($HOURS * 60)), duration_s=60.0,
                       induced="robot", seed=1)
print(f"dataset: {$HOURS:g} h in {time.perf_counter() - t:.0f} s", flush=True)
EOF
common=(--dataset "$WORK/ds" --stage scratch --epochs "$EPOCHS" --patience "$EPOCHS"
        --time-budget 1e9 --no-progress)
run() {  # name, then the command's head
    local name=$1; shift
    local t0=$SECONDS
    "$@" train "${common[@]}" --out "$WORK/$name.pt" ${EXTRA:-} > "$WORK/$name.log" 2>&1 \
        || { echo "$name failed:"; tail -20 "$WORK/$name.log"; return 0; }
    echo "$name: $(tail -1 "$WORK/$name.log") ($((SECONDS - t0)) s)"
}
TORCHRUN=("$PY" -m torch.distributed.run --standalone)
RUNS=${RUNS:-cpu cuda ddp_cuda_1 ddp_cpu_2}      # which of the four to run
want() { [[ " $RUNS " == *" $1 "* ]]; }
want cpu && EXTRA="--device cpu --threads $CORES" run cpu "$PY" -m aslip_ros.cli
if "$PY" -c "import torch, sys; sys.exit(not torch.cuda.is_available())"; then
    want cuda && EXTRA="--device cuda" run cuda "$PY" -m aslip_ros.cli
    want ddp_cuda_1 && EXTRA="--device cuda" \
        run ddp_cuda_1 "${TORCHRUN[@]}" --nproc_per_node 1 -m aslip_ros.cli
fi
want ddp_cpu_2 && EXTRA="--device cpu --threads $((CORES / 2))" \
    run ddp_cpu_2 "${TORCHRUN[@]}" --nproc_per_node 2 -m aslip_ros.cli
true
"$PY" - <<EOF
import json, os
from aslip_ros.learn.checkpoint import load_checkpoint
rows = {}
for name in ("cpu", "cuda", "ddp_cuda_1", "ddp_cpu_2"):
    path = os.path.join("$WORK", name + ".pt")
    if not os.path.exists(path):
        continue
    prov = load_checkpoint(path).meta["provenance"]
    tr, val = prov["training"], prov["metrics"]["val"]
    rows[name] = {"device": prov.get("device"), "epochs": tr["epochs_run"],
                  "s_per_epoch": round(tr["train_time_s"] / tr["epochs_run"], 3),
                  "feature_time_s": round(tr["feature_time_s"], 1),
                  "n_train_windows": tr["n_train_windows"],
                  **{k: val.get(k) for k in ("detection_accuracy", "direction_mae_deg",
                                             "magnitude_rmse_mm")}}
cpu = rows.get("cpu", {}).get("s_per_epoch")
for r in rows.values():
    r["speedup_over_cpu"] = round(cpu / r["s_per_epoch"], 2) if cpu else None
import torch
doc = {"hours": $HOURS, "epochs": $EPOCHS, "cores": $CORES, "torch": torch.__version__,
       "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
       "rows": rows}
with open(os.path.join("$OUT", "gpu_scale.json"), "w") as f:
    json.dump(doc, f, indent=1)
print(json.dumps(doc, indent=1))
EOF
