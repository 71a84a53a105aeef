#!/usr/bin/env bash
# Times the README's demo command as a new user meets it: on a fresh Debian 12 root
# (debootstrap --variant=minbase, plus git, ca-certificates and GNU time; no compiler, no
# CMake, none of tofu's packages), in a clean clone of this repository's HEAD with
# ../shared beside it. `scripts/dev.sh demo` then installs what it needs, builds `tofu` and
# flies; its time, package installation included, is the last line printed.
#
#   sudo scripts/time_demo_fresh.sh [ROOT_DIR]     (default /srv/tofu-fresh-demo)
#
# Needs root, debootstrap and Debian's mirror. ROOT_DIR is created, must not exist, and is
# left behind for inspection (the demo's outputs are in ROOT_DIR/root/w/tofu/runs/);
# the mounts it makes are undone on exit. The chroot shares this machine's kernel and
# cores, so the time is this machine's.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
fresh="${1:-/srv/tofu-fresh-demo}"
shared="$root/../shared"

[[ $(id -u) -eq 0 ]] || { echo "time_demo_fresh.sh: needs root (debootstrap, chroot)" >&2; exit 2; }
command -v debootstrap > /dev/null ||
  { echo "time_demo_fresh.sh: needs debootstrap (apt-get install debootstrap)" >&2; exit 2; }
[[ ! -e "$fresh" ]] || { echo "time_demo_fresh.sh: $fresh exists; name a new directory" >&2; exit 2; }

mounted=()
cleanup() {
  local m
  for m in "${mounted[@]}"; do umount -R "$m" 2> /dev/null || umount -lR "$m" 2> /dev/null || true; done
}
trap cleanup EXIT

debootstrap --variant=minbase bookworm "$fresh" http://deb.debian.org/debian > "$fresh.debootstrap.log" 2>&1 ||
  { echo "time_demo_fresh.sh: debootstrap failed, see $fresh.debootstrap.log" >&2; exit 1; }
# One command per line: set -e stops at a failed mount (not inside an && list), and
# rslave keeps the unmounts on exit from reaching the host's own mounts.
mount -t proc proc "$fresh/proc"
mounted+=("$fresh/proc")
for dir in sys dev; do
  mount --rbind "/$dir" "$fresh/$dir"
  mounted+=("$fresh/$dir")
  mount --make-rslave "$fresh/$dir"
done
cp /etc/resolv.conf "$fresh/etc/"
chroot "$fresh" bash -c 'apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends git ca-certificates time' > /dev/null

mkdir -p "$fresh/root/w"
git clone -q "$root" "$fresh/root/w/tofu"
if [[ -d "$shared" ]]; then cp -r "$shared" "$fresh/root/w/shared"; fi
echo "time_demo_fresh.sh: $(git -C "$root" log -1 --format='%h %cs') on a fresh Debian $(cat "$fresh/etc/debian_version") root, $(nproc) cores, $(date -u '+%Y-%m-%d %H:%M UTC')"
chroot "$fresh" env -i HOME=/root PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
  bash -c 'cd /root/w/tofu && /usr/bin/time -f "time_demo_fresh.sh: the demo took %e s wall (%U s user, %S s sys), package installation included" scripts/dev.sh demo'
