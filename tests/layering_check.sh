#!/usr/bin/env bash
# DESIGN.md layering: estimator/ never includes MuJoCo, sim/, replay/ or harness/; replay/
# (the simulator-free path) includes core/ and estimator/ only, never MuJoCo, sim/,
# harness/, renders/, report/, corpus/ or apps/; sim/ never includes estimator/, replay/ or
# harness/; core/ includes nothing of the project but core/;
# harness/ never includes renders/ and renders/ never includes harness/ (renders read
# the run directory through replay/); nothing but apps/ includes
# report/ (MCAP and HTML of finished runs), and report/ never includes apps/; nothing but
# apps/ includes corpus/, which builds on harness alone; interface/ (the protocol, the
# plug-in loader) includes the public api and core only, and only replay/, harness/ and
# apps/ include it; include/tofu (the installed api) includes nothing of the project.
set -u
root="${1:?usage: layering_check.sh SOURCE_DIR}"
status=0
check() {  # dir, forbidden-include regex, why
  local hits
  hits=$(grep -rnE "#include [<\"]($2)" "$root/$1" --include='*.h' --include='*.cc' || true)
  if [[ -n "$hits" ]]; then
    echo "layering violation ($3):"
    echo "$hits"
    status=1
  fi
}
check estimator 'mujoco/|sim/|harness/|apps/' "estimator depends on core, Eigen, Ceres only"
check estimator 'replay/' "replay builds on the estimator, never the other way"
check replay 'mujoco/|sim/|harness/|renders/|report/|corpus/|apps/' \
  "replay is the simulator-free path: core and estimator only"
check sim 'estimator/|replay/|harness/|apps/' "sim does not know who consumes its streams"
check core 'mujoco/|sim/|harness/|estimator/|replay/|apps/|ceres/' "core is the vocabulary"
check harness 'renders/|apps/' "renders read harness outputs, never the other way"
check estimator 'renders/|report/' "the estimator is a library of its own"
check harness 'report/' "reports read finished run directories"
check renders 'report/|apps/' "reports draw on renders, never the other way"
check renders 'harness/' "renders read the run directory (replay's schema), never the scenario loader"
check sim 'report/|renders/' "sim does not know who reads its runs"
check report 'apps/|corpus/' "the CLI calls reports, never the other way"
for layer in core sim estimator replay harness renders report; do
  check "$layer" 'corpus/' "corpora are built from harness runs; nothing below includes them"
done
check corpus 'apps/|renders/|report/' "corpus needs harness runs only"
check interface 'mujoco/|sim/|estimator/|replay/|harness/|renders/|report/|corpus/|apps/|ceres/' \
  "interface (the protocol and the plug-in loader) knows the public api and core only"
check include 'mujoco/|sim/|estimator/|replay/|harness/|interface/|core/|ceres/|Eigen/' \
  "the public api (include/tofu) is header-only and free of tofu's internals and Eigen"
for layer in core sim estimator; do
  check "$layer" 'interface/|tofu/' "users' estimators and controllers enter through replay and harness"
done
[[ $status == 0 ]] && echo "layering ok"
exit $status
