#!/usr/bin/env bash
# Regenerates the gallery of renders/README.md: flies the canonical failure scenarios and
# renders one frame of each off-screen (EGL; no display or GPU needed) into
# renders/gallery/, replaced as a whole once every picture is done.
#
#   scripts/render_gallery.sh        # BUILD_DIR (default build) must hold a built tofu
#
# Runs go to $GALLERY_RUNS (default runs/gallery) and are reused when already there
# (delete them to fly again). Same build, same machine => the same PNG bytes.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
tofu="${BUILD_DIR:-build}/tofu"
runs="${GALLERY_RUNS:-runs/gallery}"
if [[ ! -x "$tofu" ]]; then
  echo "render_gallery: no $tofu: build first (cmake --build ${BUILD_DIR:-build}) or set BUILD_DIR" >&2
  exit 2
fi

# A scenario's run directory: exit 1 (an expectation failed) still writes a complete run.
fly() {
  local name="$1"
  [[ -f "$runs/$name/summary.json" ]] && return 0
  mkdir -p "$runs"
  echo "flying $name"
  "$tofu" run "scenarios/$name.yaml" --out "$runs/$name" --quiet --force || [[ $? == 1 ]]
}

staging="$(mktemp -d "$root/renders/.gallery.XXXXXX")"
trap 'rm -rf "$staging"' EXIT

# shot NAME RUN TIME_S [tofu render options...]
shot() {
  local name="$1" run="$2" t="$3"
  shift 3
  "$tofu" render "$runs/$run" --at "$t" --out "$staging/$name.png" --quiet "$@"
  echo "  $name.png  ($run at $t s)"
}

fly paper_consensus_indoor
fly bridge_sensors
fly wall_sensors

echo "rendering into renders/gallery/"
# The headline picture of the project README: the consensus experiment from outside the
# arena, 12 s after VIO began to diverge (its ghost far off, the total station fused).
shot headline paper_consensus_indoor 30 --camera overview --size 560x420
shot vio_divergence_excluded paper_consensus_indoor 24 --size 400x300
shot leica_noise_detected paper_consensus_indoor 83 --size 400x300
shot leica_line_of_sight_blocked bridge_sensors 24 --size 400x300
shot gnss_sky_under_the_deck bridge_sensors 12 --sky --size 400x300
shot lidar_degenerate_facade wall_sensors 12 --lidar --size 400x300

rm -rf renders/gallery
mv "$staging" renders/gallery
trap - EXIT
du -ch renders/gallery/*.png | tail -1
