#!/usr/bin/env bash
# The installed package, as a user's out-of-tree plug-in sees it (cmake/TofuInstall.cmake,
# examples/cpp_plugin/README.md):
#   1. `cmake --install BUILD --prefix PREFIX` (a fresh temporary prefix) installs bin/tofu,
#      include/tofu/{api,plugin}.h and the CMake package, and no static library; the
#      installed tofu starts;
#   2. find_package(tofu 0.1) from PREFIX gives tofu::api and tofu_API_VERSION equal to
#      the header's TOFU_API_VERSION; find_package(tofu 0.2) is refused (SameMinorVersion);
#   3. examples/cpp_plugin configures and builds against PREFIX alone (Ninja, the compiler
#      tofu was built with, -DTOFU_EXAMPLE_TESTS=ON), and its find_package found PREFIX;
#   4. the example's unit test passes (test_filter, given the module: it also dlopens it);
#   5. the module exports tofu_plugin_api_version and tofu_create_estimator (nm -D);
#   6. the module is copied to OUT_DIR/tofu_example_filter.so, a stable path for scenario
#      tests (FIXTURES_REQUIRED tofu_example_plugin).
#   install_plugin_check.sh CMAKE BUILD_DIR SOURCE_DIR CXX_COMPILER OUT_DIR
set -euo pipefail
cmake="$1"
build_dir="$2"
source_dir="$3"
cxx="$4"
out_dir="$5"

fail() { echo "install_plugin_check: FAIL: $*" >&2; exit 1; }
command -v ninja > /dev/null || fail "ninja is not installed"
command -v nm > /dev/null || fail "nm (binutils) is not installed"

work="$(mktemp -d "${TMPDIR:-/tmp}/tofu-install-check.XXXXXX")"
trap 'rm -rf "$work"' EXIT
prefix="$work/prefix"

# ---- 1. install
"$cmake" --install "$build_dir" --prefix "$prefix" > "$work/install.log" ||
  { cat "$work/install.log"; fail "cmake --install $build_dir exit $?"; }
for f in bin/tofu include/tofu/api.h include/tofu/plugin.h; do
  [[ -e "$prefix/$f" ]] || fail "not installed: $f"
done
config="$(find "$prefix" -name tofuConfig.cmake)"
[[ -n "$config" ]] || fail "no tofuConfig.cmake under $prefix"
for f in tofuConfigVersion.cmake tofuTargets.cmake; do
  [[ -e "$(dirname "$config")/$f" ]] || fail "no $f next to $config"
done
if static="$(find "$prefix" -name '*.a' | grep .)"; then
  fail "static libraries installed: $static"
fi
"$prefix/bin/tofu" --help > /dev/null || fail "the installed tofu does not start (exit $?)"
echo "installed: $(cd "$prefix" && find . -type f | sort | tr '\n' ' ')"

# ---- 2. the package: version check and tofu_API_VERSION
header_api="$(sed -n 's/^#define[[:space:]]*TOFU_API_VERSION[[:space:]]*\([0-9][0-9]*\)[[:space:]]*$/\1/p' \
  "$prefix/include/tofu/api.h")"
[[ -n "$header_api" ]] || fail "no TOFU_API_VERSION in the installed api.h"
probe="$work/probe"
mkdir -p "$probe"
cat > "$probe/CMakeLists.txt" << 'EOF'
cmake_minimum_required(VERSION 3.22)
project(probe NONE)
find_package(tofu ${WANT} QUIET)
if(tofu_FOUND)
  if(NOT TARGET tofu::api OR NOT TARGET tofu::tofu)
    message(FATAL_ERROR "tofu found without the targets tofu::api and tofu::tofu")
  endif()
  message(STATUS "PROBE found ${tofu_VERSION} api ${tofu_API_VERSION} at ${tofu_DIR}")
else()
  message(STATUS "PROBE not-found")
endif()
EOF
probe_with() {
  rm -rf "$probe/build"
  "$cmake" -S "$probe" -B "$probe/build" -DWANT="$1" -DCMAKE_PREFIX_PATH="$prefix" \
    -DCMAKE_FIND_USE_PACKAGE_REGISTRY=OFF 2>&1 | sed -n 's/^-- PROBE //p'
}
found="$(probe_with 0.1)"
[[ "$found" == "found 0.1."*" api $header_api at $prefix/"* ]] ||
  fail "find_package(tofu 0.1) from $prefix: '$found' (want version 0.1.x, api $header_api)"
found="$(probe_with 0.2)"
[[ "$found" == "not-found" ]] || fail "find_package(tofu 0.2) accepted 0.1: '$found'"

# ---- 3. the example, out of tree, against the prefix alone
plugin_build="$work/plugin-build"
"$cmake" -S "$source_dir/examples/cpp_plugin" -B "$plugin_build" -G Ninja \
  -DCMAKE_BUILD_TYPE=Release -DCMAKE_CXX_COMPILER="$cxx" -DCMAKE_PREFIX_PATH="$prefix" \
  -DCMAKE_FIND_USE_PACKAGE_REGISTRY=OFF -DTOFU_EXAMPLE_TESTS=ON > "$work/configure.log" 2>&1 ||
  { cat "$work/configure.log"; fail "configuring examples/cpp_plugin"; }
tofu_dir="$(sed -n 's/^tofu_DIR:PATH=//p' "$plugin_build/CMakeCache.txt")"
[[ "$tofu_dir" == "$prefix/"* ]] || fail "the example found tofu at '$tofu_dir', not under $prefix"
"$cmake" --build "$plugin_build" > "$work/build.log" 2>&1 ||
  { cat "$work/build.log"; fail "building examples/cpp_plugin"; }
if grep -E 'warning:' "$work/build.log"; then
  fail "the example does not build warning-free (-Wall -Wextra -Wpedantic)"
fi
module="$plugin_build/tofu_example_filter.so"
[[ -f "$module" ]] || fail "no $module"

# ---- 4. the filter's unit test (and the module through dlopen)
"$plugin_build/test_filter" "$module" || fail "test_filter exit $?"

# ---- 5. the entry points
symbols="$(nm -D --defined-only "$module")"
for sym in tofu_plugin_api_version tofu_create_estimator tofu_destroy_estimator; do
  grep -qE "[[:space:]]T[[:space:]]+$sym\$" <<< "$symbols" || fail "$module does not export $sym"
done

# ---- 6. the module where scenario tests find it (written whole, then renamed)
mkdir -p "$out_dir"
cp "$module" "$out_dir/.tofu_example_filter.so.tmp"
mv -f "$out_dir/.tofu_example_filter.so.tmp" "$out_dir/tofu_example_filter.so"
echo "install_plugin_check: OK: $out_dir/tofu_example_filter.so (plug-in API $header_api)"
