"""Boot-process rules P001-P008: the CiA 302-2 boot-slave process (SPEC §8.4).

The reconstruction (`nmtcheck/processes/boot.py`) runs once per input before the rules, only on
channels where a manager is configured or the log shows a boot signature; each rule
reports its own code's findings from it. P rules are exempt from the UNKNOWN rule: a
probed node may never transmit.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np

from nmtcheck.checks.base import Param, Params, Problems, input_rule
from nmtcheck.processes import boot_records as boot
from nmtcheck.timeline.model import InputModel


def _found(model: InputModel, code: str) -> Iterator[Problems]:
    """One batch per channel: the findings the boot stage made, then those it only counted
    past the per-rule cap (rows the engine counts and never makes: no time, no text)."""
    analysis = boot.of(model)
    if analysis is None:
        return
    for channel, made, left in analysis.batches(code):
        k, n = len(made), len(made) + left
        time = np.full(n, np.nan)
        time[:k] = [f.time for f in made]
        idx = np.full(n, -1, np.int64)
        idx[:k] = [-1 if f.frame_index is None else f.frame_index for f in made]
        line = np.zeros(n, np.int64)
        line[:k] = [f.line or 0 for f in made]
        nodes = np.full(n, -1, np.int64)
        nodes[:k] = [f.node for f in made]
        yield Problems(channel, None, time, _messages(made), idx, line, nodes)


def _messages(made: list[boot.BootFinding]) -> Callable[[int], str]:
    def message(i: int) -> str:
        return made[i].message

    return message


@input_rule("P001", "boot-identity-mismatch", "error", exempt_from_unknown=True, scope="node")
def boot_identity_mismatch(model: InputModel, params: Params) -> Iterator[Problems]:
    """A node's identity does not match what the manager expects (letters C, D, M, N, O).

    **What it checks.** In an attempt of node N's boot process, the value the manager
    uploads from 1000h:00 (device type) or 1018h:01-04 (vendor-ID, product code, revision,
    serial number) differs from the expected non-zero value (1F84h-1F88h:N: network file
    keys `device_type` ... `serial_number`, the master DCF or `master.bin`, else N's own
    EDS); or an upload of 1018h:01-04 is refused, aborted or unanswered and not recovered
    (a manager reads 1018h:k only when it expects a value). Silent when a later attempt of
    the same process ends ok. Reported at the answer (or the abort) with the
    Lely-compatible letter and every mismatch of the process.

    **Why it matters.** A CiA 302 manager stops the boot of such a slave: it is never
    started ("Boot Issue: value of object 1018:02 ... 1F86" in ros2_canopen).

    **Example.** `602#4018100200000000` answered by `582#4318100244460000` (product code
    0x00004644) while 1F86h:2 = 0x00004645: P001, letter M.
    """
    return _found(model, "P001")


@input_rule("P002", "boot-no-response", "error", exempt_from_unknown=True, scope="node")
def boot_no_response(model: InputModel, params: Params) -> Iterator[Problems]:
    """The manager's probe (upload of 1000h:00) is never answered (letter B).

    **What it checks.** No probe of node N's boot process is answered with a value, at
    least one failed (aborted with 0504 0000h, refused or unanswered), and the manager
    stopped probing: the trace continues at least max(2 s, 2 x the longest interval
    between probes) after the last one. A manager that retries until the slave is up
    (probes before the boot-up, Lely's 4-request rounds) is silent: any probe of the
    process answered is enough. Reported at the end frame of the last failed probe.

    **Why it matters.** The slave never enters the boot process: wrong node-ID, wrong bit
    rate, SDO server disabled, or a slave that answers only after the manager gave up.

    **Example.** `602#4000100000000000` four times, each followed 100 ms later by the
    client's `602#8000100000000405`, and no answer: P002, letter B.
    """
    return _found(model, "P002")


@input_rule("P003", "boot-download-failed", "error",
            Param("restore_timeout_ms", float, "how long the manager waits for the boot-up "
                  "after a restore (1011h) and its reset", 1000.0),
            exempt_from_unknown=True, scope="node")
def boot_download_failed(model: InputModel, params: Params) -> Iterator[Problems]:
    """A configuration download of the boot process fails (letter J, or I for 1F50h/1F51h).

    **What it checks.** Between the start and the end of node N's boot process, an SDO
    download to N (expedited, segmented or block) is refused, aborted or unanswered and
    not recovered by a retry. Uploads and transfers after the process ended (application
    traffic) are not judged; unanswered or timed-out writes of 1F51h:01 = 0 or 1 are
    ignored as Lely ignores them. Reported at the abort (or the unanswered request); the
    message counts all failed downloads and says when N was started anyway.

    **Why it matters.** The slave runs with a partial configuration (wrong PDO mapping,
    no heartbeat) or is never started.

    **Example.** `602#2300140102020080` answered by `582#8000140111000906` (abort 0609
    0011h, sub-index does not exist) during the boot: P003, letter J.
    """
    return _found(model, "P003")


@input_rule("P004", "boot-no-error-control", "error",
            Param("rtr_timeout_ms", float, "how long the manager waits for the answer to its "
                  "guarding request in the keep-alive check", 100.0),
            Param("reset_timeout_ms", float, "how long the manager waits for the boot-up after "
                  "resetting a keep-alive slave", 1000.0),
            exempt_from_unknown=True, scope="node")
def boot_no_error_control(model: InputModel, params: Params) -> Iterator[Problems]:
    """No heartbeat when the manager starts error control (letter K; E/F for keep-alive).

    **What it checks.** The manager's consumer time C_N for node N is known
    (`manager_consumer_ms`, or the master DCF's 1016h entry naming N), the probe of the
    last attempt was answered and nothing else failed, and N sends neither a heartbeat
    (state other than 00h) nor a guarding response within C_N after the attempt's last
    SDO transfer (K). For a keep-alive process: no heartbeat within C_N after the identity
    check (E), or no answer to the guarding request (F). Reported when the wait expired;
    a start within the wait does not silence it.

    **Why it matters.** The manager reports the slave failed and does not start it
    (Lely) although its configuration went through: 1017h not written or 0.

    **Example.** Configuration done at 10.024 s, `manager_consumer_ms = 300`, no heartbeat
    of node 2 until 11.0 s: P004 at 10.324 s, letter K.
    """
    return _found(model, "P004")


@input_rule("P005", "boot-slave-already-operational", "info", exempt_from_unknown=True,
            scope="node")
def boot_slave_already_operational(model: InputModel, params: Params) -> Iterator[Problems]:
    """The slave reports OPERATIONAL during its boot process (letter L).

    **What it checks.** Inside node N's boot process, before any start command to N, N
    reports OPERATIONAL (a heartbeat or guarding response with state 05h that is not a
    stale report queued before a command). A CiA 302 manager then skips reset and
    configuration (keep-alive) or ends the process with letter L, and sends no start.
    For a keep-alive slave whose heartbeat the manager consumes (its 1016h entry is
    known), the process ends at N's second such report, as Lely's master does (recorded
    in `samples/lely/boot/keepalive`): the first only passes its state check.

    **Why it matters.** Not an error (ros2_canopen accepts L as booted), but the manager
    did not configure the slave: a slave that starts itself keeps its old configuration.

    **Example.** The manager boots (`701#00`) while node 2 runs, reads 1000h and node 2's
    next heartbeat is `702#05`: P005, letter L.
    """
    return _found(model, "P005")


@input_rule("P006", "mandatory-slave-not-booted", "error", exempt_from_unknown=True,
            scope="node")
def mandatory_slave_not_booted(model: InputModel, params: Params) -> Iterator[Problems]:
    """A mandatory slave did not complete its boot within the boot time (1F89h).

    **What it checks.** For each boot-up of the channel's master and each mandatory slave
    N (1F81h bits 0 and 3; `mandatory = true`) with boot time T = 1F89h > 0
    (`[boot] boot_time_ms`): no boot process of N completes within T of the master's
    boot-up, and the trace goes on past it. Silent when a P001-P004 finding already names
    the cause, when T = 0, or when the master is unknown. Letter B when no probe was
    answered by then.

    **Why it matters.** The manager halts the network boot-up: it stays PRE-OPERATIONAL
    and starts no slave all at once.

    **Example.** Master boot-up at 10.0 s, `boot_time_ms = 2000`, node 2 mandatory and not
    started by 12.0 s: P006 at 12.0 s.
    """
    return _found(model, "P006")


@input_rule("P007", "start-before-boot-complete", "error", exempt_from_unknown=True,
            scope="node")
def start_before_boot_complete(model: InputModel, params: Params) -> Iterator[Problems]:
    """A start command reaches a slave whose boot process is not complete.

    **What it checks.** A start command to node N (direct, or broadcast) arrives while N
    has an open boot process in which an SDO transfer is still open, no probe has been
    answered, or an identity mismatch (P001) holds. Reported at the command. Silent when
    N's process already completed, when N has no process, and after a P003 or P004
    failure (that finding reports the start).

    **Why it matters.** The slave goes OPERATIONAL with a half-written configuration:
    PDOs with the old mapping, no heartbeat yet.

    **Example.** `602#2F60600001000000` (6060h download) then `000#0100` before the
    `582#60...` confirmation: P007.
    """
    return _found(model, "P007")


@input_rule("P008", "boot-stalled", "warning",
            Param("stall_ms", float, "how long a boot process may stay open before it counts "
                  "as stalled", 10000.0),
            exempt_from_unknown=True, scope="node")
def boot_stalled(model: InputModel, params: Params) -> Iterator[Problems]:
    """A boot process stops without a verdict: no start, no failure, no further request.

    **What it checks.** Node N's boot process is still open `stall_ms` after its start,
    the trace goes on, no P001-P004 or P006 finding explains it, the manager starts slaves
    (configured, or seen starting another) and N is not waiting for a broadcast start.
    The message names the last step, its value and line, and the candidate letters
    (inferred from the last step, never asserted).

    **Why it matters.** This is the "stuck on *Wait for device to boot*" pattern: the
    manager silently rejected the slave (an identity it expects, a heartbeat it waits for)
    or its own configuration step never finished.

    **Example.** Node 2 answers 1000h, 1018h:01 and 1018h:02, then nothing happens while
    node 3 is started: P008 10 s later, "candidates M, K, no start".
    """
    return _found(model, "P008")
