#!/usr/bin/env python3
"""The test-layer check of CTest (`layers.test_executables`), from CMake's own
dependency graph: configures the source tree into a scratch directory with
`cmake --graphviz` and checks, in the per-target graphs it writes
(deps.dot.<target>), that every module test executable (<module>_tests)
reaches only what soma_<module> reaches plus the test helpers, and every
benchmark (soma_bench_<module>_<name>) only what soma_<module> and the lower
modules named for it reach plus Google Benchmark. The configure-time check
(soma_check_test_layers, cmake/SomaHelpers.cmake) walks the same links through
target properties; this one reads the graph a user sees.

usage: check_test_layers.py SOURCE_DIR SCRATCH_DIR MODULES BENCH_LOWER EXEMPT
                            [CMAKE_ARGS...]
  MODULES      the soma libraries in definition (layer) order, ','-separated
  BENCH_LOWER  '<module>=<lib>,<lib>:...': lower modules a module's
               benchmarks may link besides their own
  EXEMPT       ','-separated executables that link the whole framework on
               purpose (tests/bench/CMakeLists.txt says why)
Prints one line per violation and exits 1 if there is any.
"""
import os
import re
import subprocess
import sys

NODE = re.compile(r'^\s*"(node\d+)" \[ label = "([^"\\]*)(?:\\n[^"]*)?"')
EDGE = re.compile(r'^\s*"(node\d+)" -> "(node\d+)"')

TEST_HELPERS = {"soma_testing", "soma_testing_main", "GTest::gmock", "GTest::gtest"}
BENCH_HELPERS = {"benchmark::benchmark", "benchmark::benchmark_main"}


def reachable(graph_dir, target):
    """Labels of every node of deps.dot.<target> (the target's dependencies,
    transitively), the target excluded; None if CMake wrote no such file."""
    path = os.path.join(graph_dir, "deps.dot." + target)
    if not os.path.isfile(path):
        return None
    labels = {}
    for line in open(path):
        m = NODE.match(line)
        if m:
            labels[m.group(1)] = m.group(2)
    return {label for label in labels.values() if label != target}


def main():
    source, scratch, modules, bench_lower, exempt = sys.argv[1:6]
    exempt = set(filter(None, exempt.split(",")))
    modules = [m for m in modules.split(",") if m]
    lower = {}
    for item in filter(None, bench_lower.split(":")):
        module, libs = item.split("=", 1)
        lower[module] = [lib for lib in libs.split(",") if lib]
    graph_dir = os.path.join(scratch, "graph")
    os.makedirs(graph_dir, exist_ok=True)
    for name in os.listdir(graph_dir):
        os.remove(os.path.join(graph_dir, name))
    configure = subprocess.run(
        ["cmake", "-S", source, "-B", scratch,
         "--graphviz=" + os.path.join(graph_dir, "deps.dot")] + sys.argv[6:],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if configure.returncode != 0:
        print(configure.stdout[-4000:])
        print(f"check_test_layers: configuring {source} into {scratch} failed")
        return 1

    closures = {}
    for lib in modules:
        closure = reachable(graph_dir, lib)
        if closure is not None:
            closures[lib] = closure | {lib}
    if not closures:
        print(f"check_test_layers: no graph of {modules} in {graph_dir}")
        return 1

    errors = []
    checked = 0
    for name in sorted(os.listdir(graph_dir)):
        if not name.startswith("deps.dot.") or name.endswith(".dependers"):
            continue
        target = name[len("deps.dot."):]
        if target in exempt:
            continue
        m = re.fullmatch(r"(\w+)_tests", target)
        b = re.fullmatch(r"soma_bench_([a-z]+)_\w+", target)
        if m and "soma_" + m.group(1) in closures:
            module = m.group(1)
            allowed = set(closures["soma_" + module]) | TEST_HELPERS
            if "soma_body" in allowed:
                allowed |= {"soma_testing_body"}
        elif b and "soma_" + b.group(1) in closures:
            module = b.group(1)
            allowed = set(closures["soma_" + module]) | BENCH_HELPERS
            position = modules.index("soma_" + module)
            for lib in lower.get(module, []):
                if lib not in closures or modules.index(lib) > position:
                    errors.append(f"{target}: {lib} is not a module below {module}")
                    continue
                allowed |= closures[lib]
        else:
            continue  # not a module test or benchmark (integration_tests, soma)
        deps = reachable(graph_dir, target)
        checked += 1
        for dep in sorted(deps - allowed):
            if dep.startswith("soma") or dep in ("torch", "Ceres::ceres"):
                errors.append(f"{target} (module {module}) reaches {dep}, "
                              f"which soma_{module} does not")
    # Third-party libraries come in through the soma libraries they reach, so
    # only soma libraries, torch and Ceres are named above; an executable
    # linking another library directly is not a layer question.
    for error in errors:
        print(error)
    print(f"check_test_layers: {checked} executables, {len(errors)} violations "
          f"(graphs: {graph_dir})")
    return 1 if errors or checked == 0 else 0


if __name__ == "__main__":
    sys.exit(main())
