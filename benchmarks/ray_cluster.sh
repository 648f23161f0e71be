#!/usr/bin/env bash
# A two-node Ray cluster on loopback (a head and a second node, 1 CPU each), then a
# 2-seed sweep through --address: each trial should run on its own node, and the table
# should equal the local sweep's (the same seeds). Prints the node of each trial and the
# wall-clock of each phase. Needs the ray extra: pip install -e ".[ray]".
set -euo pipefail
cd "$(dirname "$0")/.."
work=$(mktemp -d)
port=${PORT:-6390}
# Multi-node on one machine must be allowed explicitly; Ray >= 2.59 clusters use tokens.
export RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=1 RAY_AUTH_MODE=token RAY_USAGE_STATS_ENABLED=0
export RAY_worker_niceness=0 OMP_NUM_THREADS=1
# Each node runs in the foreground of its own session (--block), so that stopping it
# signals only its process group: `ray stop` would stop every Ray on the machine.
pids=()
stop_nodes() {
  for pid in "${pids[@]}"; do kill -TERM -- "-$pid" 2>/dev/null || true; done
  sleep 5
  for pid in "${pids[@]}"; do kill -KILL -- "-$pid" 2>/dev/null || true; done
  rm -rf "$work"
}
trap stop_nodes EXIT
wait_for() { for _ in $(seq 600); do grep -q "$2" "$1" 2>/dev/null && return 0; sleep 0.5; done; return 1; }
start=$(date +%s.%N)
setsid ray start --head --block --node-ip-address 127.0.0.1 --port "$port" --num-cpus 1 \
  --include-dashboard=false --temp-dir "$work/ray" >"$work/head.log" 2>&1 &
pids+=($!)
wait_for "$work/head.log" "block forever"
setsid ray start --block --address "127.0.0.1:$port" --node-ip-address 127.0.0.1 --num-cpus 1 \
  >"$work/node.log" 2>&1 &
pids+=($!)
wait_for "$work/node.log" "block forever"
up=$(date +%s.%N)
python -m minitaur_env.sweep --address "127.0.0.1:$port" -f "$work/sweeps" \
  --env Pendulum-v1 --seeds 2 -n 600 --eval-freq 200 --eval-episodes 2 \
  --hyperparams learning_starts=100 batch_size=32 "policy_kwargs={net_arch: [32]}"
done_at=$(date +%s.%N)
echo "nodes of the trials:"; grep -h '^node:' "$work"/sweeps/*/runs/*/trial.yml | sort | uniq -c
python - "$start" "$up" "$done_at" <<'PY'
import sys
start, up, done = map(float, sys.argv[1:])
print(f"cluster start: {up - start:.1f} s; sweep: {done - up:.1f} s; total {done - start:.1f} s")
PY
