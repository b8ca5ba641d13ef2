#!/usr/bin/env bash
# Builds the Fast DDS peer (peer.cpp) against Debian's Fast DDS into OUT_DIR/fastdds_peer: the
# DDS IDL of ttball's interfaces made from msgs/ by ROS 2's interface tools
# (tests/interop/rosidl/dds_idl.py: rosidl_adapter, rosidl_parser), fastddsgen's type support,
# g++; DISTRO (jazzy, the default, or humble) picks the layout of the ros_discovery_info it
# reads. Also writes what rosidl read of msgs/ to OUT_DIR/rosidl.json (TTBALL_ROSIDL_JSON).
# Needs libfastrtps-dev, fastddsgen, python3-rosidl, rosidl-tools, python3-catkin-pkg and
# python3-empy (Debian's packages; .ci/run installs them).
# Usage: build.sh OUT_DIR [DISTRO]
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
out="$1"
distro="${2:-jazzy}"
rm -rf "$out/rosidl"
mkdir -p "$out/gen"
/usr/bin/python3 "$here/../rosidl/dds_idl.py" "$here/../../../msgs" "$out/rosidl" \
  --json "$out/rosidl.json" --distro "$distro" > "$out/ttball.idl" 2> "$out/rosidl.log" || {
  cat "$out/rosidl.log" >&2
  exit 1
}
tail -n 1 "$out/rosidl.log"
(cd "$out" && fastddsgen -replace -d gen ttball.idl >/dev/null)
g++ -std=c++14 -O1 -o "$out/fastdds_peer" "$here/peer.cpp" "$out/gen/ttball.cxx" \
  "$out/gen/ttballPubSubTypes.cxx" -I"$out/gen" -lfastrtps -lfastcdr
