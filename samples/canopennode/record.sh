#!/bin/sh
# Re-record every scenario (see README.md). Run in this folder after `make`.
#   ./record.sh [BINDIR] [OUTDIR]
# BINDIR: where `make` put dev, dev_toggle, dev_syncskip, dev_inhibit, dev_late, dev_emcyshort and lss_dev
#         (default /work/build/canopennode/bin)
# OUTDIR: where the logs go (default: this folder); device events go to OUTDIR/*.events.
# The SYNC and EMCY scenarios go to OUTDIR/sync_emcy/, with their .events (the stack's
# own callbacks: the ground truth that tests/test_samples_sync_emcy.py reads), the PDO
# scenarios to OUTDIR/pdo/, with theirs (tests/test_samples_pdo.py), the LSS scenarios to
# OUTDIR/lss/ (tests/test_samples_lss.py).
set -e
BIN=${1:-/work/build/canopennode/bin}
OUT=${2:-.}
for s in healthy late_master write_1017 self_start master_obeys broadcast guard_toggle duplicate_id \
         unplugged_heartbeat unplugged_guarded stopped_sdo power_cycle nmt_direct master_unplugged \
         hb_runtime reset_node_all guarded_power_cycle guarded_power_cycle_stored sync_pdo; do
  chrt -f 10 python3 hub.py $s "$OUT/$s.log" --bin "$BIN" --events "$OUT/$s.events"
done
mkdir -p "$OUT/sync_emcy"
for s in sync_producer_stopped sync_counter sync_counter_skip emcy_inhibit sync_length emcy_short \
         sync_period_fast; do
  chrt -f 10 python3 hub.py $s "$OUT/sync_emcy/$s.log" --bin "$BIN" --events "$OUT/sync_emcy/$s.events"
done
mkdir -p "$OUT/pdo"
for s in rpdo_producer_stopped rpdo_timeout_stale_heartbeat tpdo_event_timer tpdo_inhibit_bypass rpdo_length sync_tpdo \
         reserved_type tpdo_late tpdo_late_written; do
  chrt -f 10 python3 hub.py $s "$OUT/pdo/$s.log" --bin "$BIN" --events "$OUT/pdo/$s.events"
done
mkdir -p "$OUT/lss"
for s in lss_configure_store lss_fastscan_one lss_fastscan_two lss_fastscan_nobody lss_selective_nobody \
         lss_store_error lss_two_in_configuration lss_bitrate_silent lss_not_adopted; do
  chrt -f 10 python3 hub.py $s "$OUT/lss/$s.log" --bin "$BIN" --events "$OUT/lss/$s.events"
done
# Lely's LSS master (samples/lely/lss/: lely_lss built there into BIN, lely-core in /opt/lely)
for s in lely_selective_nobody lely_configure_after_waiting lely_fastscan lely_fastscan_configured; do
  LD_LIBRARY_PATH=/opt/lely/lib chrt -f 10 python3 hub.py $s "$OUT/../lely/lss/$s.log" --bin "$BIN" \
    --events "$OUT/../lely/lss/$s.events"
done
