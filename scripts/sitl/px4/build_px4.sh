#!/usr/bin/env bash
# Build PX4 SITL (SIH quadrotor, headless, lockstep) with the MRFT of abdullaayyad96/PX4-Autopilot (issue 42).
#
# usage: scripts/sitl/px4/build_px4.sh DEST [SOURCE]
#   DEST    folder for the source tree and build (e.g. ~/sitl/px4); reused if already built
#   SOURCE  optional: a PX4 source folder (a clone of abdullaayyad96/PX4-Autopilot branch main, or upstream
#           PX4 of 2024-08 with its submodules), or a bare git directory plus revision as GIT_DIR@REV.
#           Without SOURCE the script clones the fork at $PX4_COMMIT and its submodules.
# Environment: PX4_COMMIT (default below), SKIP_APT=1, NO_MRFT=1 (build the base without the patch),
#              MAVLINK_MIRROR / PYMAVLINK_MIRROR / GPSDRIVERS_MIRROR / LIBEVENTS_MIRROR / HEATSHRINK_MIRROR:
#              bare git dirs for the submodules (offline build).
# The MRFT patch (mrft_port.patch beside this script) is applied before the build: it carries the fork's
# branch-`mrft` files (PX4 v1.11.3) onto PX4 main of 2024-08, where SIH runs in SITL.
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
DEST=${1:?usage: build_px4.sh DEST [SOURCE]}
SRC=${2:-}
# Pinned: the fork's branch main (PX4 main of 2024-08-21).
PX4_COMMIT=${PX4_COMMIT:-ae165561076541efd2db00b28a05ad42c190b9ff}
MAVLINK_COMMIT=bb52e30d2b924d5a250f2400144d33012271a19d
PYMAVLINK_COMMIT=533161c47995ba47f5548636eed37a47e91072c0
GPSDRIVERS_COMMIT=a41210ede8c2d22dd8e9fdcf388fca927c1fc5e1
LIBEVENTS_COMMIT=9474657606d13301d426e044450c4f84de2221be
HEATSHRINK_COMMIT=052e6de72f67f1777198bce98f3de62f7f3c16a0

if [ "${SKIP_APT:-0}" != 1 ] && command -v apt-get >/dev/null; then
  SUDO=$([ "$(id -u)" = 0 ] && echo "" || echo sudo)
  $SUDO apt-get install -y --no-install-recommends $(grep -v '^#' "$HERE/apt-packages.txt") || \
    echo "warning: apt-get failed; continuing with what is installed"
fi

extract() { python3 "$HERE/../extract_tree.py" "$1" "$2" "$3"; }
commit_tree() {  # each submodule folder and the top folder must be git repositories of their own
  ( cd "$1" && [ -e .git ] || { git init -q && git add -A >/dev/null &&
    git -c user.email=sitl@localhost -c user.name=sitl commit -qm snapshot >/dev/null; } )
}
submodule() {  # submodule PATH URL COMMIT MIRROR
  local path=$1 url=$2 commit=$3 mirror=${4:-}
  if [ -e "$DEST/$path/.git" ] || [ -n "$(ls -A "$DEST/$path" 2>/dev/null)" ]; then return; fi
  if [ -n "$mirror" ]; then
    mkdir -p "$DEST/$path"; extract "$mirror" "$commit" "$DEST/$path"; commit_tree "$DEST/$path"
  else
    rm -rf "$DEST/$path"; git clone -q "$url" "$DEST/$path" && git -C "$DEST/$path" checkout -q "$commit"
  fi
}

if [ ! -e "$DEST/Makefile" ]; then
  if [ -z "$SRC" ]; then
    git clone -q https://github.com/abdullaayyad96/PX4-Autopilot.git "$DEST"
    git -C "$DEST" checkout -q "$PX4_COMMIT"
  elif [[ "$SRC" == *@* ]]; then
    mkdir -p "$DEST"; extract "${SRC%@*}" "${SRC##*@}" "$DEST"
  else
    mkdir -p "$DEST"; cp -a "$SRC/." "$DEST/"
  fi
fi
cd "$DEST"
if [ -e .git ] && [ -z "${MAVLINK_MIRROR:-}" ]; then
  git submodule update --init src/modules/mavlink/mavlink src/drivers/gps/devices src/lib/events/libevents \
    src/lib/heatshrink/heatshrink 2>/dev/null || true
fi
submodule src/modules/mavlink/mavlink https://github.com/mavlink/mavlink.git "$MAVLINK_COMMIT" "${MAVLINK_MIRROR:-}"
submodule src/modules/mavlink/mavlink/pymavlink https://github.com/ArduPilot/pymavlink.git "$PYMAVLINK_COMMIT" "${PYMAVLINK_MIRROR:-}"
submodule src/drivers/gps/devices https://github.com/PX4/PX4-GPSDrivers.git "$GPSDRIVERS_COMMIT" "${GPSDRIVERS_MIRROR:-}"
submodule src/lib/events/libevents https://github.com/mavlink/libevents.git "$LIBEVENTS_COMMIT" "${LIBEVENTS_MIRROR:-}"
submodule src/lib/heatshrink/heatshrink https://github.com/PX4/heatshrink.git "$HEATSHRINK_COMMIT" "${HEATSHRINK_MIRROR:-}"

# uXRCE-DDS and gyro FFT: their sources are third-party submodules a headless SIH run does not need.
sed -i -e 's/^CONFIG_MODULES_UXRCE_DDS_CLIENT=y/CONFIG_MODULES_UXRCE_DDS_CLIENT=n/' \
       -e 's/^CONFIG_MODULES_GYRO_FFT=y/CONFIG_MODULES_GYRO_FFT=n/' boards/px4/sitl/default.px4board
# The build parses the version from git's latest tag.
if [ ! -e .git ]; then
  git init -q && git add -A >/dev/null && git -c user.email=sitl@localhost -c user.name=sitl commit -qm snapshot >/dev/null
fi
git tag -l | grep -q . || git tag v1.15.0
# The MRFT port (idempotent: applied once, checked by its marker file).
if [ "${NO_MRFT:-0}" != 1 ] && [ ! -e src/lib/MRFT/.mrft_port_applied ]; then
  git apply --whitespace=nowarn "$HERE/mrft_port.patch"
  touch src/lib/MRFT/.mrft_port_applied
fi
# The roll and pitch MRFT (mrft-ident's: the fork has none on the rate loop): MRFT_R_* and MRFT_P_* in
# mc_rate_control, the fork's relay on the roll (pitch) angle as the roll (pitch) torque setpoint, its
# output held MRFT_DELAY ms, its decision logged in debug_vect (mrft_roll.patch; applied once, after the
# port). A tree patched by an earlier version (markers .mrft_roll_applied, .mrft_rate_applied) gets
# mc_rate_control back from its snapshot first.
if [ "${NO_MRFT:-0}" != 1 ] && [ ! -e src/lib/MRFT/.mrft_rate_delay_applied ]; then
  if [ -e src/lib/MRFT/.mrft_roll_applied ] || [ -e src/lib/MRFT/.mrft_rate_applied ]; then
    git checkout -q HEAD -- src/modules/mc_rate_control
  fi
  git apply --whitespace=nowarn "$HERE/mrft_roll.patch"
  touch src/lib/MRFT/.mrft_rate_delay_applied
fi

if [ ! -x venv/bin/python ]; then
  python3 -m venv venv
  venv/bin/pip install -q -r "$HERE/requirements-build.txt"
fi
export PATH="$DEST/venv/bin:$PATH" GIT_SUBMODULES_ARE_EVIL=1
[ -e build/px4_sitl_default/build.ninja ] || \
  cmake -S . -B build/px4_sitl_default -G Ninja -DCONFIG=px4_sitl_default
ninja -C build/px4_sitl_default -j"$(nproc)"
ls -l build/px4_sitl_default/bin/px4
