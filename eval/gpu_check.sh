#!/usr/bin/env bash
# The device check for a lent GPU machine (no Open3D, no network there): the C++ extension's build, every `cuda`
# test, `panorecon bench --quick --device cuda`, the target command trained on CUDA with gsplat, and then blocks of
# the paper's tables at the paper's settings (1024 px, 128² labels, 240 labels, 10,000 steps) until the deadline.
# Prepare on a machine with Open3D and pip, in the repository root (.whl and gpu are git-ignored there):
#   mkdir -p .whl gpu/cache/lpips; python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 \
#     --implementation cp --platform manylinux_2_28_x86_64 -d .whl gsplat==1.5.3 dlr-moge==2.0.0 dlr-utils3d==1.3 \
#     plyfile==1.1.3 pyamg==5.4.1    # the machine has neither (panorecon.io.ply, the fusion's multigrid)
#   panorecon render bedroom --out gpu/bed128 --width 128 --heldout 2 --heldout-res 32
#   panorecon render bedroom --out gpu/bed512 --width 512 --heldout-res 256
#   for s in bedroom bathroom library exhibition-hall mountain grassland beach city-plaza; do
#     panorecon render $s --width 1024 --heldout 8 --heldout-res 128 --heldout-seeds 0 1 2 --out gpu/tables/$s; done
#   cp ~/.cache/panorecon/lpips/alex_v0.1.pt gpu/cache/lpips/    # the LPIPS weights scripts/setup.sh converted
# then run `bash eval/gpu_check.sh OUTDIR` there with .whl and gpu carried (about 40 MB). Python with CUDA torch is
# `python3`. `bash eval/gpu_check.sh OUTDIR tables` runs only the tables step (a second call on the same machine).
# Environment: GPU_TABLES, the suites to run (default "table7", the adaptive-pruning claim, 2 runs a block);
# GPU_CHECK_UNTIL, seconds after the start at which the tables step is stopped (default 560, inside one call's
# 600 s); GPU_TABLE_SETTINGS, the --set options (default the paper's); GPU_DEVICE (default cuda).
# The tables resume from benchmarks/tables/gpu/<suite>/results.csv (the rows committed so far) and every finished
# run is in OUTDIR/<suite>.csv: commit that as benchmarks/tables/gpu/<suite>/results.csv and regenerate its report
# with `panorecon ablate --from-csv benchmarks/tables/gpu/<suite>/results.csv eval/suites/<suite>.toml --out ...`.
set -u
out=${1:?usage: eval/gpu_check.sh OUTDIR [tables]}
only_tables=$([ "${2:-}" = tables ] && echo 1 || echo 0)
mkdir -p "$out"
t0=$(date +%s)
until=${GPU_CHECK_UNTIL:-560}
step() { echo "[t+$(($(date +%s) - t0))s] $*"; }
if compgen -G ".whl/*.whl" > /dev/null; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 3
fi
export PYTHONPATH=/tmp/site:$PWD TORCH_CUDA_ARCH_LIST=${TORCH_CUDA_ARCH_LIST:-9.0} PYTHONUNBUFFERED=1
[ -d gpu/cache ] && export PANORECON_CACHE=$PWD/gpu/cache  # the LPIPS weights carried, the C++ build
python3 -c "import sys, torch; print(sys.version.split()[0], torch.__version__, torch.cuda.get_device_name())"
"${CXX:-c++}" --version | head -1
panorecon=(python3 -c "import sys; from panorecon.cli import main; sys.exit(main(sys.argv[1:]))")
if [ "$only_tables" = 0 ]; then
  sed 's#scene = \["bedroom"\]#scene = ["gpu/bed128"]#' eval/suites/bench.toml > /tmp/bench_suite.toml
  step build the C++ extension
  timeout 300 python3 -c "
import time; t = time.time()
from panorecon.splat.rasterize import cpu_backend as c
print('cpu extension built:', c.available(), c.unavailable_reason() or '', round(time.time() - t, 1), 's')"
  step build gsplat
  timeout 300 python3 -c "import gsplat; from gsplat.cuda._backend import _C; print('gsplat', gsplat.__version__, _C is not None)"
  step cuda tests
  timeout 300 python3 -m pytest -m cuda -q -p no:cacheprovider -rs tests/splat/test_rasterize_gsplat.py \
      tests/splat/test_trainer_device.py tests/fusion/test_fusion.py 2>&1 | tee "$out/cuda_tests.log" | tail -8
  timeout 200 python3 -m pytest -q -p no:cacheprovider tests/splat/test_cpu_backend_build.py 2>&1 | tail -2
  step bench
  timeout 300 "${panorecon[@]}" bench --quick --device cuda --suite /tmp/bench_suite.toml --out "$out/bench_cuda.json" \
      > "$out/bench.log" 2>&1
  echo "bench rc=$?"
  step target command
  timeout 300 "${panorecon[@]}" train gpu/bed512 --source fibonacci --teacher sim:relative --res 256 --labels 240 \
      --device cuda --no-progress --out /tmp/gpu_target > "$out/train.log" 2>&1
  echo "train rc=$?"; tail -1 "$out/train.log"; cp /tmp/gpu_target/metrics.json "$out/train_metrics.json"
fi
left=$((until - $(date +%s) + t0))
tables=(${GPU_TABLES:-table7})
suites=(); for t in "${tables[@]}"; do suites+=("eval/suites/$t.toml"); done
settings=(${GPU_TABLE_SETTINGS:---set width=1024 --set res=128 --set labels=240 --set iters=10000 --set eval_at=[300,1000,3000]})
where() { if [ "${#tables[@]}" = 1 ]; then echo "$1"; else echo "$1/$2"; fi; }  # ablate's folder for one suite
if [ ! -d gpu/tables ]; then
  step "tables skipped: no gpu/tables (see this script's header)"
elif [ "$left" -lt 120 ]; then
  step "tables skipped: ${left}s left before GPU_CHECK_UNTIL=$until"
else
  step "tables ${tables[*]} (${settings[*]}) for ${left}s"
  for t in "${tables[@]}"; do
    done_csv=benchmarks/tables/gpu/$t/results.csv
    if [ -f "$done_csv" ] && [ ! -f "$(where /tmp/gpu_tables "$t")/results.csv" ]; then
      mkdir -p "$(where /tmp/gpu_tables "$t")"; cp "$done_csv" "$(where /tmp/gpu_tables "$t")/results.csv"
    fi
  done
  timeout -k 20 "$left" "${panorecon[@]}" ablate "${suites[@]}" --scene-dir gpu/tables \
      --out /tmp/gpu_tables --device "${GPU_DEVICE:-cuda}" --jobs 1 --no-progress "${settings[@]}" \
      > "$out/tables.log" 2>&1
  echo "tables rc=$? (124: stopped at the deadline; its finished runs are kept)"
  grep -E '^\[[0-9]+/[0-9]+\]|runs:|distinct' "$out/tables.log"
  for t in "${tables[@]}"; do
    csv=$(where /tmp/gpu_tables "$t")/results.csv
    [ -f "$csv" ] && cp "$csv" "$out/$t.csv"
  done
fi
step done
