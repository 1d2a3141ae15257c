#!/usr/bin/env bash
# System packages swarmd's tests and demo use, from Debian's archive. Idempotent.
# - libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6: headless MuJoCo rendering
#   (MUJOCO_GL=egl or osmesa, see docs/physics.md)
# - systemd: `systemd-analyze verify` of deploy/ units
# - iproute2: network-namespace multicast test (`ip netns`)
# - shellcheck: lint of deploy/install.sh and this script (tests/test_deploy.py)
set -euo pipefail
pkgs=(libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6 systemd iproute2 shellcheck)
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  exit 0
fi
if [ "$(id -u)" -ne 0 ]; then
  echo "system-deps: need root to apt-get install: ${missing[*]} (tests that need them will skip)" >&2
  exit 0
fi
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
apt-get install -y -qq --no-install-recommends "${missing[@]}"
