#!/bin/sh
# Re-record every scenario (see README.md). Run in this folder after `make`.
#   ./record.sh [BINDIR] [OUTDIR]
# BINDIR: where `make` put dev and dev_toggle (default /work/build/canopennode/bin)
# OUTDIR: where the logs go (default: this folder); device events go to OUTDIR/*.events
set -e
BIN=${1:-/work/build/canopennode/bin}
OUT=${2:-.}
for s in healthy late_master write_1017 self_start master_obeys broadcast guard_toggle duplicate_id \
         unplugged_heartbeat unplugged_guarded stopped_sdo power_cycle nmt_direct master_unplugged \
         hb_runtime reset_node_all guarded_power_cycle guarded_power_cycle_stored sync_pdo; do
  chrt -f 10 python3 hub.py $s "$OUT/$s.log" --bin "$BIN" --events "$OUT/$s.events"
done
