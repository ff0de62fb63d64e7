#!/usr/bin/env bash
# The installed somalab, as another project sees it (issue #21 item 4):
#   1. `cmake --install <build> --prefix <tmp>/prefix`;
#   2. the installed `soma` run from an unrelated directory finds its configs,
#      models and bundled take beside itself (--cfg job, then the main job);
#   3. an external CMake project (tests/install/consumer) finds the package,
#      registers its own noise module, composes a config with it and runs.
#   install_test.sh <build dir> <source dir>
set -euo pipefail
build=$(realpath "$1")
source=$(realpath "$2")
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
prefix="$work/prefix"
fail() { echo "install_test: FAIL: $*" >&2; exit 1; }

cmake --install "$build" --prefix "$prefix" >"$work/install.log" ||
  { tail -20 "$work/install.log"; fail "cmake --install"; }
for f in bin/soma lib/libsoma_framework.a include/somalab/framework/framework.h \
  share/somalab/configs/config.yaml share/somalab/models/README.md \
  lib/cmake/somalab/somalabConfig.cmake lib/cmake/somalab/somalabTargets.cmake; do
  [[ -e "$prefix/$f" ]] || fail "$f not installed"
done

mkdir "$work/elsewhere"
cd "$work/elsewhere"
# No SOMA_HOME and no source tree: the binary must find share/somalab.
env -u SOMA_HOME -u SOMA_SOURCE_DIR "$prefix/bin/soma" --cfg job >cfg.txt 2>err.txt ||
  { cat err.txt; fail "installed soma --cfg job"; }
grep -q "name: label_eval" cfg.txt || fail "--cfg job did not print the main job"
env -u SOMA_HOME -u SOMA_SOURCE_DIR "$prefix/bin/soma" hydra.run.dir=run >main.txt 2>&1 ||
  { tail -5 main.txt; fail "installed soma (main job)"; }
grep -q "label_eval: tracklet" main.txt || fail "the main job printed no summary"
[[ -f run/summary.md && -f run/per_frame/eval.md && -f run/tracklet/confusion.png ]] ||
  fail "the main job's outputs are missing"
case "$(cat run/summary.md)" in *"$prefix/share/somalab/models/"*) ;; *)
  fail "the main job did not use the installed bundled model" ;; esac

cmake -S "$source/tests/install/consumer" -B "$work/consumer-build" \
  -DCMAKE_PREFIX_PATH="$prefix" -DCMAKE_BUILD_TYPE=Release >"$work/consumer.log" 2>&1 ||
  { tail -30 "$work/consumer.log"; fail "configuring the consumer project"; }
cmake --build "$work/consumer-build" -j"$(nproc)" >>"$work/consumer.log" 2>&1 ||
  { tail -30 "$work/consumer.log"; fail "building the consumer project"; }
"$work/consumer-build/consumer" noise=drift hydra.run.dir=consumer_run >consumer.txt 2>&1 ||
  { cat consumer.txt; fail "running the consumer"; }
grep -q "pipeline: drift(p=1.0)" consumer.txt || { cat consumer.txt; fail "the consumer's module was not composed"; }
grep -q "x_sum: 0.500" consumer.txt || { cat consumer.txt; fail "the consumer's module did not run"; }
echo "install_test: ok (prefix $prefix)"
