#!/usr/bin/env bash
# The device check for a lent GPU machine (no Open3D, no network there): the C++ extension's build, every `cuda`
# test, `panorecon bench --quick --device cuda`, and the target command trained on CUDA with gsplat.
# Prepare on a machine with Open3D and pip, in the repository root (both folders are git-ignored there):
#   mkdir -p .whl gpu; python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 \
#     --implementation cp --platform manylinux_2_28_x86_64 -d .whl gsplat==1.5.3 dlr-moge==2.0.0 dlr-utils3d==1.3
#   panorecon render bedroom --out gpu/bed128 --width 128 --heldout 2 --heldout-res 32
#   panorecon render bedroom --out gpu/bed512 --width 512 --heldout-res 256
# then run `bash eval/gpu_check.sh OUTDIR` there with .whl and gpu carried. Python with CUDA torch is `python3`.
set -u
out=${1:?usage: eval/gpu_check.sh OUTDIR}
mkdir -p "$out"
t0=$(date +%s)
step() { echo "[t+$(($(date +%s) - t0))s] $*"; }
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 3
export PYTHONPATH=/tmp/site:$PWD TORCH_CUDA_ARCH_LIST=${TORCH_CUDA_ARCH_LIST:-9.0} PYTHONUNBUFFERED=1
python3 -c "import sys, torch; print(sys.version.split()[0], torch.__version__, torch.cuda.get_device_name())"
"${CXX:-c++}" --version | head -1
sed 's#scene = \["bedroom"\]#scene = ["gpu/bed128"]#' eval/suites/bench.toml > "$out/bench_suite.toml"
panorecon=(python3 -c "import sys; from panorecon.cli import main; sys.exit(main(sys.argv[1:]))")
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
timeout 300 "${panorecon[@]}" bench --quick --device cuda --suite "$out/bench_suite.toml" --out "$out/bench_cuda.json" \
    > "$out/bench.log" 2>&1
echo "bench rc=$?"
step target command
timeout 300 "${panorecon[@]}" train gpu/bed512 --source fibonacci --teacher sim:relative --res 256 --labels 240 \
    --device cuda --no-progress --out /tmp/gpu_target > "$out/train.log" 2>&1
echo "train rc=$?"; tail -1 "$out/train.log"; cp /tmp/gpu_target/metrics.json "$out/train_metrics.json"
step done
