"""The rule registry: one explicit table, in catalogue order. Adding a rule = a module + a line."""

from __future__ import annotations

from nmtcheck.checks.base import Rule
from nmtcheck.checks.boot import (
    boot_download_failed,
    boot_identity_mismatch,
    boot_no_error_control,
    boot_no_response,
    boot_slave_already_operational,
    boot_stalled,
    mandatory_slave_not_booted,
    start_before_boot_complete,
)
from nmtcheck.checks.bootup import bootup_repeated, missing_bootup, unexpected_bootup
from nmtcheck.checks.canid import (
    malformed_error_control,
    malformed_nmt_command,
    restricted_can_id,
    unknown_nmt_state,
)
from nmtcheck.checks.emcy import emcy_active_at_end, emcy_inhibit_violation, emcy_malformed
from nmtcheck.checks.guarding import (
    guard_interval_exceeded,
    guard_no_response,
    guard_toggle,
    guarding_with_heartbeat,
)
from nmtcheck.checks.heartbeat import (
    consumer_without_producer,
    heartbeat_period_mismatch,
    heartbeat_timeout,
    heartbeat_too_early,
)
from nmtcheck.checks.inputs import (
    frames_lost,
    no_timestamps,
    nothing_to_check,
    recording_gap,
    skipped_records,
    timestamps_backwards,
    truncated_input,
)
from nmtcheck.checks.lss import (
    lss_error_response,
    lss_fastscan,
    lss_no_response,
    lss_node_id_not_adopted,
    lss_not_in_configuration,
    lss_selective_no_match,
    lss_several_responders,
)
from nmtcheck.checks.network import duplicate_node_id, missing_node
from nmtcheck.checks.pdo import (
    pdo_length_mismatch,
    reserved_transmission_type,
    rpdo_deadline_missed,
    sync_tpdo_count,
    tpdo_event_timer_exceeded,
    tpdo_inhibit_violation,
)
from nmtcheck.checks.state import (
    comm_while_stopped,
    command_not_obeyed,
    pdo_to_not_operational,
    pdo_while_not_operational,
    unexplained_state_change,
)
from nmtcheck.checks.sync import (
    sync_counter_sequence,
    sync_frame_invalid,
    sync_pdo_outside_window,
    sync_period_mismatch,
    sync_timeout,
)

RULES: list[Rule] = [
    missing_bootup,
    unexpected_bootup,
    bootup_repeated,
    heartbeat_timeout,
    heartbeat_too_early,
    heartbeat_period_mismatch,
    consumer_without_producer,
    guard_toggle,
    guard_no_response,
    guard_interval_exceeded,
    guarding_with_heartbeat,
    pdo_while_not_operational,
    pdo_to_not_operational,
    comm_while_stopped,
    command_not_obeyed,
    unexplained_state_change,
    restricted_can_id,
    malformed_nmt_command,
    malformed_error_control,
    unknown_nmt_state,
    missing_node,
    duplicate_node_id,
    boot_identity_mismatch,
    boot_no_response,
    boot_download_failed,
    boot_no_error_control,
    boot_slave_already_operational,
    mandatory_slave_not_booted,
    start_before_boot_complete,
    boot_stalled,
    sync_timeout,
    sync_frame_invalid,
    sync_counter_sequence,
    sync_pdo_outside_window,
    sync_period_mismatch,
    tpdo_event_timer_exceeded,
    tpdo_inhibit_violation,
    sync_tpdo_count,
    rpdo_deadline_missed,
    pdo_length_mismatch,
    reserved_transmission_type,
    emcy_inhibit_violation,
    emcy_malformed,
    emcy_active_at_end,
    lss_no_response,
    lss_selective_no_match,
    lss_error_response,
    lss_not_in_configuration,
    lss_several_responders,
    lss_node_id_not_adopted,
    lss_fastscan,
    nothing_to_check,
    truncated_input,
    skipped_records,
    frames_lost,
    timestamps_backwards,
    no_timestamps,
    recording_gap,
]

BY_CODE: dict[str, Rule] = {r.code: r for r in RULES}
