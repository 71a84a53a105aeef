#!/usr/bin/env bash
# DESIGN.md layering, at link time: estimator_only_tests (the estimator's and replay's
# simulator-free unit tests, linked against tofu::replay) must not load MuJoCo. Fails when
# ldd lists libmujoco, or when ldd cannot read the binary.
set -u
binary="${1:?usage: estimator_only_libs_check.sh BINARY}"
if ! libs=$(ldd "$binary" 2>&1); then
  echo "ldd failed on $binary:"
  echo "$libs"
  exit 1
fi
if hits=$(grep -i 'libmujoco' <<<"$libs"); then
  echo "layering violation (estimator and replay are usable without the simulator):"
  echo "$binary loads"
  echo "$hits"
  exit 1
fi
echo "estimator_only_tests: no libmujoco ($(wc -l <<<"$libs") shared libraries)"
