#!/usr/bin/env bash
# Soak test of `ttball node` (not run by CI: it takes MINUTES minutes). A Cyclone DDS peer
# (tests/interop/dds_peer.py) publishes a simulated 150 + 900 fps rally of about MINUTES minutes
# at its recorded pace, inside a loopback-only network namespace; the node's resident memory is
# sampled every 10 s; at the end the node is stopped with SIGTERM and prints its summary.
#
#   TTBALL_PYTHON=/path/to/python-with-cyclonedds tests/soak/node_soak.sh [MINUTES] [OUT_DIR]
#
# Passes (exit 0) when the node exits 0, its peak resident memory is within 10 % of its
# resident memory after the first minute, and every detection the peer sent is accounted for in
# the node's summary (fused + initialising + rejected = received; what the wire lost, best
# effort as ROS 2 sensor data, is reported).
set -euo pipefail
minutes=${1:-10}
out=${2:-target/soak}
root=$(cd "$(dirname "$0")/../.." && pwd)
python=${TTBALL_PYTHON:?set TTBALL_PYTHON to a Python with cyclonedds and mcap (see .ci/run)}
mkdir -p "$out"
out=$(cd "$out" && pwd)
cargo build --release --quiet --manifest-path "$root/Cargo.toml"
ttball="$root/target/release/ttball"
# 52 shots are 71 s of play.
shots=$(( minutes * 60 * 52 / 71 + 1 ))
"$ttball" simulate --shots "$shots" --no-truth --seed 7 -o "$out/soak.mcap" > /dev/null
unshare -n bash -c "
set -e
ip link set lo up; ip link set lo multicast on; ip route add 224.0.0.0/4 dev lo
export ROS_DOMAIN_ID=44 ROS_LOCALHOST_ONLY=1
cd '$out'
'$ttball' node > node.out 2> node.err &
node=\$!
( while kill -0 \$node 2> /dev/null; do
    echo \"\$(date +%s) \$(awk '/VmRSS/ {print \$2}' /proc/\$node/status 2> /dev/null)\"; sleep 10
  done ) > rss.txt &
'$python' '$root/tests/interop/dds_peer.py' publish soak.mcap --count-only --wait-match 30 --linger 3 \
    --out peer.json 2> peer.err
kill -TERM \$node
wait \$node
echo \$? > node.rc
"
cat "$out/node.out"
cat "$out/peer.err"
"$python" - "$out" <<'PY'
import json, re, sys
out = sys.argv[1]
rss = [int(l.split()[1]) for l in open(f"{out}/rss.txt") if len(l.split()) == 2]
summary = open(f"{out}/node.out").read()
peer = json.load(open(f"{out}/peer.json"))
num = lambda label: int(re.search(label + r" (\d+)", summary).group(1))
received, fused, init, rejected = (num(x) for x in ("detections received", "fused", "initialising", "rejected"))
rc = open(f"{out}/node.rc").read().strip()
after_minute = rss[min(6, len(rss) - 1)]
print(f"soak: node exit {rc}; sent {peer['sent']}, received {received} ({peer['sent'] - received} lost on "
      f"the wire; fused {fused} + initialising {init} "
      f"+ rejected {rejected}); states {peer['states']}, intercepts {peer['intercepts']}; resident memory "
      f"{after_minute / 1024:.1f} MB after 1 min, peak {max(rss) / 1024:.1f} MB, last {rss[-1] / 1024:.1f} MB "
      f"over {len(rss)} samples")
ok = (rc == "0" and received <= peer["sent"] and fused + init + rejected == received
      and max(rss) <= 1.1 * after_minute)
sys.exit(0 if ok else 1)
PY
