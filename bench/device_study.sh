#!/usr/bin/env bash
# Issue 30's accelerator measurements in one command, for a machine with a GPU and its own
# JAX (the device tool's machines run JAX 0.11 with CUDA; nothing is installed, jaxvo is
# read from this checkout). STEPS picks among:
#   bench    bench/bench_study.py: vmapped call against a loop of scans, the sharded runner
#            on the device, and a study of SIZED configurations of one sequence at the batch
#            `jaxvo study` chooses against each hand-picked batch of CURVE;
#   example  the example study (examples/thesis_parameters.toml) through the CLI as a user
#            runs it (its batch "chosen"), or at each batch of EXAMPLE_BATCHES (default "chosen");
#   pipeline bench/bench_pipeline.py on that machine: `jaxvo run` and OpenCV's odometry as
#            processes, `Odometry` streaming (its step on the CPU), the whole-sequence scan on
#            the accelerator;
#   tests    TEST_PATHS (default the study and pipeline tests) on that JAX (CPU backend):
#            jaxvo runs on the JAX users install.
# Results go to OUT as at most 8 plain files (the device tool brings back no more).
#
# Run: [STEPS="bench example tests"] bash bench/device_study.sh OUT [SIZED] [CURVE]
set -u
out=${1:?usage: bench/device_study.sh OUT [SIZED] [CURVE]}
sized=${2:-4096}
curve=${3:-64,256,1024,4096}
steps=${STEPS:-bench example tests}
mkdir -p "$out"
export PYTHONPATH=$PWD PYTHONUNBUFFERED=1
py=${PYTHON:-python3}
work=$(mktemp -d)

{ $py -c "import jax, cv2, optax, chex; print('jax', jax.__version__, jax.devices(), \
'opencv', cv2.__version__)"; nvidia-smi --query-gpu=name,memory.total,memory.used \
  --format=csv 2>/dev/null; } 2>&1 | tee "$out/env.txt"

if [[ " $steps " == *" bench "* ]]; then
  timeout "${BENCH_TIMEOUT:-330}" $py bench/bench_study.py --batch 8 --repeats 2 --no-scaling \
    --devices 1 --sized "$sized" --curve "$curve" --out "$work/bench" 2>&1 \
    | tee "$out/bench_study.log"
  cp "$work"/bench/study.json "$work"/bench/study.md "$out"/ 2>/dev/null
fi

if [[ " $steps " == *" pipeline "* ]]; then
  timeout "${PIPELINE_TIMEOUT:-150}" $py bench/bench_pipeline.py --warm-runs 1 --peer-runs 1 \
    --out "$work/pipeline" 2>&1 | tee "$out/pipeline.log"
  cp "$work"/pipeline/pipeline.json "$work"/pipeline/pipeline.md "$out"/ 2>/dev/null
fi

if [[ " $steps " == *" example "* ]]; then
  i=0
  for b in ${EXAMPLE_BATCHES:-chosen}; do
    i=$((i + 1))
    arg=(); [[ $b == chosen ]] || arg=(--batch "$b")
    echo "== example study, batch $b"
    ( time timeout "${EXAMPLE_TIMEOUT:-150}" $py -m jaxvo.cli study \
      examples/thesis_parameters.toml --out "$work/example_$i" --flow-cache "$work/flows" \
      "${arg[@]}" ) 2>&1 | grep -v '^jaxvo study \['
  done 2>&1 | tee "$out/example_study.log"
  cp "$work"/example_1/summary.md "$out"/example_summary.md 2>/dev/null
fi

if [[ " $steps " == *" tests "* ]]; then
  JAX_PLATFORMS=cpu timeout "${TEST_TIMEOUT:-150}" $py -m pytest -q -p no:cacheprovider \
    ${PYTEST_ARGS--n 8 -m "not slow"} ${TEST_PATHS:-tests/test_study.py tests/test_pipeline.py} \
    2>&1 | tail -40 | tee "$out/tests.log"
fi
