#!/usr/bin/env bash
# Builds the Fast DDS peer (peer.cpp) against Debian's Fast DDS into OUT_DIR/fastdds_peer:
# the IDL of ttball's interfaces from msgs/ (msg2idl.py), fastddsgen's type support, g++.
# Needs libfastrtps-dev and fastddsgen (apt-get install libfastrtps-dev fastddsgen).
# Usage: build.sh OUT_DIR
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
out="$1"
mkdir -p "$out/gen"
python3 "$here/msg2idl.py" "$here/../../../msgs" > "$out/ttball.idl"
(cd "$out" && fastddsgen -replace -d gen ttball.idl >/dev/null)
g++ -std=c++14 -O1 -o "$out/fastdds_peer" "$here/peer.cpp" "$out/gen/ttball.cxx" \
  "$out/gen/ttballPubSubTypes.cxx" -I"$out/gen" -lfastrtps -lfastcdr
