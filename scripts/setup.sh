#!/usr/bin/env bash
# Installs what tofu needs and is missing.
#   scripts/setup.sh          everything: the Debian packages of packages.txt and
#                             packages-test.txt, Node.js and npm when there is no node
#                             (Debian's nodejs and npm: a machine may have its own node,
#                             which Debian's npm package would conflict with), and the npm
#                             packages of tests/node from its lock file (`npm ci`: the exact
#                             versions of package-lock.json, from the npm registry)
#   scripts/setup.sh --demo   only packages.txt: what building and running `tofu` needs
# Idempotent and non-interactive: a second run installs nothing and touches no package
# list.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"

lists=("$here/packages.txt" "$here/packages-test.txt")
with_tests=1
case "${1:-}" in
  "") ;;
  --demo) lists=("$here/packages.txt"); with_tests=0 ;;
  *) echo "usage: scripts/setup.sh [--demo]" >&2; exit 2 ;;
esac

missing=()
while read -r pkg; do
  [[ -z "$pkg" || "$pkg" == \#* ]] && continue
  if ! dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$pkg")
  fi
done < <(cat "${lists[@]}")

if [[ $with_tests == 1 ]] && { ! command -v node > /dev/null || ! command -v npm > /dev/null; }; then
  missing+=(nodejs npm)
fi

if ((${#missing[@]} == 0)); then
  echo "setup: all packages present"
else
  echo "setup: installing ${missing[*]}"
  sudo_cmd=()
  if [[ $(id -u) -ne 0 ]]; then sudo_cmd=(sudo); fi
  export DEBIAN_FRONTEND=noninteractive
  "${sudo_cmd[@]}" apt-get update -qq
  "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

[[ $with_tests == 1 ]] || exit 0
# tests/node: installed again only when the lock file changed since the last install.
node_dir="$here/../tests/node"
stamp="$node_dir/node_modules/.tofu-lock-installed"
if [[ ! -f "$stamp" ]] || ! cmp -s "$node_dir/package-lock.json" "$stamp"; then
  echo "setup: npm ci in tests/node"
  (cd "$node_dir" && npm ci --no-audit --no-fund --loglevel=error)
  cp "$node_dir/package-lock.json" "$stamp"
else
  echo "setup: tests/node packages present"
fi
