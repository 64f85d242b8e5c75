#!/usr/bin/env bash
# Build ArduCopter SITL (headless) for the mrft-ident SITL campaign (issue 41).
#
# usage: scripts/sitl/build_ardupilot.sh DEST [SOURCE]
#   DEST    folder for the source tree and build (e.g. ~/sitl/ardupilot); reused if already built
#   SOURCE  optional: an ArduPilot source folder (a clone of any release, submodules checked out or not),
#           or a bare git directory plus revision as GIT_DIR@REV (what this project's machines have).
#           Without SOURCE the script clones upstream ArduPilot at $AP_COMMIT with its submodules.
# Environment: AP_COMMIT (default: the pinned commit below), SKIP_APT=1 to skip apt-get,
#              WAF_MIRROR / MAVLINK_MIRROR / PYMAVLINK_MIRROR: bare git dirs for the submodules (offline build).
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
DEST=${1:?usage: build_ardupilot.sh DEST [SOURCE]}
SRC=${2:-}
# Pinned: upstream ArduPilot master, ArduCopter 4.7.0-dev (the tree /work/shared/sitl/README.md built).
AP_COMMIT=${AP_COMMIT:-90700977c553d2dfd95a305acf1c3e098e4d9477}
WAF_COMMIT=35eadbb64e2052099a853b571e507c33032b392c
MAVLINK_COMMIT=4924617b8ddd9871506a01e16675a41464fdba49
PYMAVLINK_COMMIT=aa033552599c981b3e916b42383de8a21754c9b4

# Built, with this project's main-loop relay patch at its current version: nothing to do.
BIN="$DEST/build/sitl/bin/arducopter"
if [ -x "$BIN" ] && [ -e "$DEST/ArduCopter/MRFT_task.cpp" ] && \
   [ -z "$(find "$HERE/ardupilot_patch" -newer "$BIN" -type f)" ]; then echo "already built: $BIN"; exit 0; fi

# 1. System packages (Debian/Ubuntu): compiler, git, Python headers for the venv.
if [ "${SKIP_APT:-0}" != 1 ] && command -v apt-get >/dev/null; then
  SUDO=$([ "$(id -u)" = 0 ] && echo "" || echo sudo)
  $SUDO apt-get install -y --no-install-recommends $(grep -v '^#' "$HERE/apt-packages.txt") || \
    echo "warning: apt-get failed; continuing with what is installed"
fi

extract() {  # extract GIT_DIR REV DEST: the tree of REV, skipping blobs a snapshot lacks
  python3 "$HERE/extract_tree.py" "$1" "$2" "$3"
}
submodule() {  # submodule PATH URL COMMIT MIRROR
  local path=$1 url=$2 commit=$3 mirror=${4:-}
  if [ -e "$DEST/$path/.git" ] || [ -n "$(ls -A "$DEST/$path" 2>/dev/null)" ]; then return; fi
  if [ -n "$mirror" ]; then
    mkdir -p "$DEST/$path"; extract "$mirror" "$commit" "$DEST/$path"
  else
    rm -rf "$DEST/$path"; git clone -q "$url" "$DEST/$path" && git -C "$DEST/$path" checkout -q "$commit"
  fi
}

# 2. Source tree.
if [ ! -e "$DEST/wscript" ]; then
  if [ -z "$SRC" ]; then
    git clone -q https://github.com/ArduPilot/ardupilot.git "$DEST"
    git -C "$DEST" checkout -q "$AP_COMMIT"
  elif [[ "$SRC" == *@* ]]; then
    mkdir -p "$DEST"; extract "${SRC%@*}" "${SRC##*@}" "$DEST"
  else
    mkdir -p "$DEST"; cp -a "$SRC/." "$DEST/"
  fi
fi
cd "$DEST"
# A user's clone pins its own submodules: prefer them.
if [ -e .git ] && [ -z "${WAF_MIRROR:-}" ]; then
  git submodule update --init modules/waf modules/mavlink 2>/dev/null || true
  git -C modules/mavlink submodule update --init pymavlink 2>/dev/null || true
fi
submodule modules/waf https://github.com/ArduPilot/waf.git "$WAF_COMMIT" "${WAF_MIRROR:-}"
submodule modules/mavlink https://github.com/ArduPilot/mavlink.git "$MAVLINK_COMMIT" "${MAVLINK_MIRROR:-}"
submodule modules/mavlink/pymavlink https://github.com/ArduPilot/pymavlink.git "$PYMAVLINK_COMMIT" "${PYMAVLINK_MIRROR:-}"

# 3. SITL without CAN and littlefs (their submodules are not needed for a headless copter), and the
#    MRFT relay as a main-loop task (ardupilot_patch/: three new files in ArduCopter/, two lines in
#    Copter.cpp; docs/sitl.md says why).
python3 "$HERE/patch_boards.py" Tools/ardupilotwaf/boards.py
python3 "$HERE/ardupilot_patch/apply_patch.py" . || \
  echo "warning: building without the main-loop relay; the Lua script then runs the relay itself (MRFT_MAIN 0)"
# The build reads its version from git.
if [ ! -e .git ]; then
  git init -q && git add -A >/dev/null && git -c user.email=sitl@localhost -c user.name=sitl commit -qm "snapshot" >/dev/null
fi

# 4. Python for waf.
if [ ! -x venv/bin/python ]; then
  python3 -m venv venv
  venv/bin/pip install -q -r "$HERE/requirements-waf.txt"
fi
# 5. Configure and build (about 5 minutes on 2 cores with gcc 12).
# (configure once: waf then rebuilds only what changed, e.g. the patch's two files)
if [ ! -e build/c4che/sitl_cache.py ]; then
  venv/bin/python ./waf configure --board sitl --disable-networking --no-submodule-update
fi
venv/bin/python ./waf copter -j"$(nproc)"
ls -l build/sitl/bin/arducopter
