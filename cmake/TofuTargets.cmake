# Helpers that give every module the same shape: one static library `tofu_<name>`
# (alias `tofu::<name>`) built from <name>/*.cc, warnings per target, never global flags.

function(tofu_set_warnings target)
  # -Wshadow=local is GCC's; clang (the TOFU_FUZZ build) has no such option.
  target_compile_options(${target} PRIVATE -Wall -Wextra -Wpedantic
                         $<$<CXX_COMPILER_ID:GNU>:-Wshadow=local>
                         $<$<CXX_COMPILER_ID:GNU>:-fno-semantic-interposition>
                         # a precompiled header the compiler cannot use is said, not skipped
                         $<$<BOOL:${TOFU_PRECOMPILE_HEADERS}>:-Winvalid-pch>)
  if(TOFU_SANITIZE)
    # Eigen turns EIGEN_MALLOC_ALREADY_ALIGNED off under ASan, which makes our objects free
    # with its hand-made aligned allocator what the prebuilt libceres allocated with plain
    # malloc (an Eigen ABI mismatch, reported by ASan as a heap-buffer-overflow). glibc's
    # and ASan's malloc both align to 16 bytes on x86-64, so keep Eigen's default.
    target_compile_definitions(${target} PRIVATE EIGEN_MALLOC_ALREADY_ALIGNED=1)
    target_compile_options(${target} PRIVATE -fsanitize=address,undefined -fno-omit-frame-pointer)
    target_link_options(${target} PRIVATE -fsanitize=address,undefined)
  endif()
  if(TOFU_FUZZ)
    # libFuzzer build (fuzz/, docs/FUZZING.md): coverage instrumentation without
    # libFuzzer's main, plus ASan + UBSan; the fuzz targets link -fsanitize=fuzzer. Same
    # Eigen allocator caveat as TOFU_SANITIZE above.
    target_compile_definitions(${target} PRIVATE EIGEN_MALLOC_ALREADY_ALIGNED=1)
    target_compile_options(${target} PRIVATE -fsanitize=fuzzer-no-link,address,undefined
                           -fno-omit-frame-pointer)
    target_link_options(${target} PRIVATE -fsanitize=address,undefined)
  endif()
endfunction()

# The headers nearly every translation unit parses (the standard library's, Eigen's, fmt's),
# precompiled: once in core for the libraries below Ceres (core, sim, interface), and once
# with Ceres, nlohmann/json and yaml-cpp in estimator for those above it, which take it
# over (PRECOMPILED_HEADERS_FROM estimator). A library that takes a header it does not
# include gains nothing it could use: its files still #include what they use, and
# TOFU_PRECOMPILE_HEADERS=OFF builds without any, which is how a translation unit that
# forgot an #include is caught (the sanitized build). The code compiled is the same: a
# precompiled header only saves parsing (docs/BENCHMARKS.md, "Compiling tofu").
set(TOFU_COMMON_PRECOMPILED_HEADERS <algorithm> <array> <cmath> <cstdint> <functional> <map>
    <memory> <optional> <stdexcept> <string> <string_view> <utility> <vector> <Eigen/Core>
    <Eigen/Geometry> <fmt/format.h>)

function(tofu_add_library name)
  cmake_parse_arguments(ARG "" "PRECOMPILED_HEADERS_FROM" "DEPS;PRECOMPILED_HEADERS" ${ARGN})
  if(ARG_PRECOMPILED_HEADERS_FROM AND ARG_PRECOMPILED_HEADERS)
    message(FATAL_ERROR "tofu_add_library(${name}): PRECOMPILED_HEADERS_FROM takes another "
                        "library's precompiled header as it is; name its headers there")
  endif()
  file(GLOB sources CONFIGURE_DEPENDS ${PROJECT_SOURCE_DIR}/${name}/*.cc)
  add_library(tofu_${name} STATIC ${sources})
  add_library(tofu::${name} ALIAS tofu_${name})
  # Headers are included as "<module>/<header>.h" from the project root.
  target_include_directories(tofu_${name} PUBLIC ${PROJECT_SOURCE_DIR})
  target_link_libraries(tofu_${name} PUBLIC ${ARG_DEPS})
  tofu_set_warnings(tofu_${name})
  if(TOFU_PRECOMPILE_HEADERS AND ARG_PRECOMPILED_HEADERS_FROM)
    target_precompile_headers(tofu_${name} REUSE_FROM tofu_${ARG_PRECOMPILED_HEADERS_FROM})
  elseif(TOFU_PRECOMPILE_HEADERS)
    target_precompile_headers(tofu_${name} PRIVATE ${TOFU_COMMON_PRECOMPILED_HEADERS}
                              ${ARG_PRECOMPILED_HEADERS})
  endif()
  if(TOFU_SANITIZE OR TOFU_FUZZ)
    target_link_options(tofu_${name} INTERFACE -fsanitize=address,undefined)
  endif()
endfunction()
