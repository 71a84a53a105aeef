#!/usr/bin/env bash
# DESIGN.md's layer table, checked: each layer's files may include the project layers and
# the heavy third-party libraries of its own row and nothing else of them. The table below
# is that table; a change to it is a change to DESIGN.md first.
#   project layers: core sim estimator interface replay harness renders report corpus campaign
#   apps,
#   and tofu/ (the installed api, include/tofu)
#   guarded third-party headers: mujoco/ (MuJoCo), ceres/ (Ceres)
set -u
root="${1:?usage: layering_check.sh SOURCE_DIR}"
layers=(core sim estimator interface replay harness renders report corpus campaign apps tofu mujoco ceres)
declare -A may_include=(
  [core]="core"
  [sim]="core sim mujoco"
  [estimator]="core estimator ceres"
  [interface]="interface tofu"
  [replay]="core estimator interface replay tofu"
  [harness]="core sim estimator interface replay harness tofu mujoco"
  [renders]="core sim replay renders mujoco"
  [report]="core sim replay harness renders report campaign mujoco"
  [corpus]="core sim replay harness corpus"
  [campaign]="core replay harness corpus campaign"
  [apps]="core sim estimator interface replay harness renders report corpus campaign apps tofu"
  [include]="tofu"
)
declare -A why=(
  [core]="core is the vocabulary: nothing of the project but itself"
  [sim]="sim does not know who consumes its streams"
  [estimator]="the estimator is a library of its own: core, Eigen and Ceres"
  [interface]="interface (the protocol and the plug-in loader) knows the public api only"
  [replay]="replay is the simulator-free path"
  [harness]="renders, reports and corpora read harness runs, never the other way"
  [renders]="renders read the run directory (replay's schema), never the scenario loader"
  [report]="reports read finished runs; the CLI calls them"
  [corpus]="corpora are built from harness runs"
  [campaign]="campaigns fly many runs as tofu run processes and read their typed records; they never fly one in-process"
  [apps]="the CLI is the top"
  [include]="the public api is header-only and free of tofu's internals and Eigen"
)
status=0
for dir in "${!may_include[@]}"; do
  forbidden=()
  for layer in "${layers[@]}"; do
    [[ " ${may_include[$dir]} " == *" $layer "* ]] || forbidden+=("$layer/")
  done
  [[ $dir == include ]] && forbidden+=("Eigen/")
  regex=$(IFS='|'; echo "${forbidden[*]}")
  hits=$(grep -rnE "#include [<\"]($regex)" "$root/$dir" --include='*.h' --include='*.cc' || true)
  if [[ -n "$hits" ]]; then
    echo "layering violation: $dir may include ${may_include[$dir]} (${why[$dir]}):"
    echo "$hits"
    status=1
  fi
done
[[ $status == 0 ]] && echo "layering ok"
exit $status
