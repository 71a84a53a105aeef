#!/usr/bin/env bash
# Installs the Debian packages of scripts/packages.txt that are missing, Node.js and npm
# when there is no node (Debian's nodejs and npm: a machine may have its own node, which
# Debian's npm package would conflict with), and the npm packages of tests/node from its
# lock file (`npm ci`: the exact versions of package-lock.json, from the npm registry).
# Idempotent and non-interactive: a second run installs nothing and touches no package
# list.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"

missing=()
while read -r pkg; do
  [[ -z "$pkg" || "$pkg" == \#* ]] && continue
  if ! dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$pkg")
  fi
done < "$here/packages.txt"

if ! command -v node > /dev/null || ! command -v npm > /dev/null; then
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
