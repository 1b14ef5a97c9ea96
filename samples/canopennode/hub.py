#!/usr/bin/env python3
"""Userspace CAN bus ("hub") and scenario driver for the CANopenNode recordings.

usage: hub.py SCENARIO OUT.log [--bin DIR] [--events FILE]
       hub.py                    (lists the scenarios)

The hub owns a UNIX datagram socket DIR/hub.sock (DIR: a fresh temporary
directory). Every device is one process of `dev` (CANopenNode v4, see dev.c)
with its own datagram socket DIR/dev-NAME.sock. A device sends each CAN frame
to the hub as soon as CANopenNode calls CO_CANsend(). The hub is the bus: it
takes frames in the order they arrive, timestamps each one (CLOCK_REALTIME,
microseconds), writes it to the log as one candump -L line and delivers it to
every other plugged device - never back to its sender, as a CAN controller does
not receive its own frames.

Scenario actions (relative to the hub's start): spawn a device (power on),
kill it (power off), unplug/plug it (the process keeps running; its frames do
not reach the bus and bus frames do not reach it), or send it a control
command (dev.c: nmt, sdo_read, emcy_set, ...) - the master application then
sends the NMT command or SDO request itself through CANopenNode.

Device stderr (what the devices did: SDO results, NMT commands, control
commands) goes to --events (default: OUT.log with suffix .events).
"""
import os
import select
import socket
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, NamedTuple, TextIO, TypedDict

# type, rtr, dlc, pad, id, data (hub_frame_t in CO_driver_target.h)
FRAME = struct.Struct("<BBBBI8s")

MASTER = ["--node", "1", "--hb", "200", "--master", "--slaves", "2h,3h,4g", "--reset-all"]
SYNC_CONS = ["--sync-cons-us", "20000", "--sync-ovf", "4"]  # a SYNC consumer of sync_counter

ActionKind = Literal["spawn", "kill", "unplug", "plug", "ctl"]


@dataclass(frozen=True)
class Action:
    """One scenario step, `t` seconds after the hub's start."""

    t: float
    kind: ActionKind
    dev: str
    args: tuple[str, ...] = ()  # spawn: the device's command-line options
    binary: str = "dev"  # spawn: the program in --bin to run
    cmd: str = ""  # ctl: the control command (dev.c)


class Scenario(NamedTuple):
    duration: float
    actions: list[Action]


class Stats(TypedDict):
    logged: int
    dropped_unplugged: int
    delivered: int


@dataclass
class Device:
    proc: subprocess.Popen[bytes]
    addr: str
    plugged: bool = True


def spawn(t: float, dev: str, args: Sequence[str], binary: str = "dev") -> Action:
    return Action(t, "spawn", dev, args=tuple(args), binary=binary)


def ctl(t: float, dev: str, cmd: str) -> Action:
    return Action(t, "ctl", dev, cmd=cmd)


def kill(t: float, dev: str) -> Action:
    return Action(t, "kill", dev)


def unplug(t: float, dev: str) -> Action:
    return Action(t, "unplug", dev)


def plug(t: float, dev: str) -> Action:
    return Action(t, "plug", dev)


def slave(n: int, *extra: str) -> list[str]:
    return ["--node", str(n), "--hb", "1000", *extra]


def boot(toggle: bool = False) -> list[Action]:
    """Common start: slaves 2, 3 (heartbeat) and 4 (node guarding) and the master power on
    together."""
    return [
        spawn(0.0, "s2", slave(2)),
        spawn(0.0, "s3", slave(3)),
        spawn(0.0, "s4", slave(4), "dev_toggle" if toggle else "dev"),
        spawn(0.0, "master", MASTER),
    ]


SCENARIOS: dict[str, Scenario] = {
    "healthy": Scenario(10.0, boot()),
    "late_master": Scenario(12.0, [
        spawn(0.0, "s2", slave(2)),
        spawn(0.0, "s3", slave(3)),
        spawn(0.0, "s4", slave(4)),
        spawn(2.0, "master", MASTER),
    ]),
    "write_1017": Scenario(10.0, [
        spawn(0.0, "s2", slave(2)),
        spawn(0.0, "s3", slave(3)),
        spawn(0.0, "s4", slave(4)),
        spawn(1.7, "master", [a for a in MASTER if a != "--reset-all"]),
    ]),
    "self_start": Scenario(10.0, [
        spawn(0.0, "s2", slave(2)),
        spawn(0.0, "s3", slave(3, "--self-start")),
        spawn(0.0, "s4", slave(4)),
        spawn(1.5, "master", MASTER),
    ]),
    "master_obeys": Scenario(12.0, [
        *boot(),
        ctl(4.0, "master", "nmt 82 0"),
        ctl(7.0, "master", "nmt 02 0"),
        ctl(9.0, "master", "nmt 01 0"),
    ]),
    "broadcast": Scenario(10.0, [
        *boot(),
        ctl(4.0, "master", "nmt 80 0"),
        ctl(6.0, "master", "nmt 01 0"),
    ]),
    "guard_toggle": Scenario(8.0, boot(toggle=True)),
    "duplicate_id": Scenario(10.0, [
        spawn(0.0, "s2", slave(2)),
        spawn(0.0, "s3a", slave(3, "--self-start", "--no-tpdo")),
        spawn(3.52, "s3b", slave(3, "--no-tpdo")),
    ]),
    "unplugged_heartbeat": Scenario(12.0, [
        *boot(),
        unplug(5.0, "s3"),
        plug(7.0, "s3"),
    ]),
    "unplugged_guarded": Scenario(12.0, [
        *boot(),
        unplug(5.0, "s4"),
        plug(7.0, "s4"),
    ]),
    "stopped_sdo": Scenario(10.0, [
        *boot(),
        ctl(4.0, "master", "nmt 02 3"),
        ctl(4.5, "master", "sdo_read 3 1018 1"),
        ctl(5.2, "s3", "emcy_set"),
        ctl(6.0, "master", "nmt 01 3"),
        ctl(7.0, "s3", "emcy_clear"),
        ctl(7.5, "master", "sdo_read 3 1018 1"),
    ]),
    # ---- power cycles, direct commands, run-time 1017h, SYNC ----------------------
    # node 2 power-cycled while OPERATIONAL (off 0.6 s); the master application
    # re-configures and starts it 0.2 s after its boot-up
    "power_cycle": Scenario(10.0, [
        *boot(),
        kill(4.0, "s2"),
        spawn(4.6, "s2", slave(2)),
        ctl(4.8, "master", "config 2"),
    ]),
    # direct NMT commands to single slaves: stop, pre-op, start, reset node
    # (node 2, then re-configured), stop and reset communication (node 4,
    # guarded; CANopenNode keeps 1017h = 0, 100Ch, 100Dh in RAM) and start
    "nmt_direct": Scenario(10.0, [
        *boot(),
        ctl(2.0, "master", "nmt 02 2"),
        ctl(3.0, "master", "nmt 80 2"),
        ctl(4.0, "master", "nmt 01 2"),
        ctl(5.0, "master", "nmt 81 2"),
        ctl(5.5, "master", "config 2"),
        ctl(6.5, "master", "nmt 02 4"),
        ctl(7.5, "master", "nmt 82 4"),
        ctl(8.5, "master", "nmt 01 4"),
    ]),
    # the master is unplugged for 2 s: the slaves' heartbeat consumers (600 ms)
    # and node 4's life guarding (300 ms) fire, the slaves drop to
    # PRE-OPERATIONAL (CO_NMT_ERR_ON_ERR_REG); nobody restarts them
    "master_unplugged": Scenario(10.0, [
        *boot(),
        unplug(4.0, "master"),
        plug(6.0, "master"),
    ]),
    # 1017h changed at run time by SDO, no NMT command: node 2 100 -> 300 -> 50 ms,
    # node 3 100 -> 0 (heartbeat off) -> 100 ms
    "hb_runtime": Scenario(10.0, [
        *boot(),
        ctl(3.0, "master", "sdo_write 2 1017 0 2 300"),
        ctl(5.0, "master", "sdo_write 2 1017 0 2 50"),
        ctl(6.0, "master", "sdo_write 3 1017 0 2 0"),
        ctl(7.5, "master", "sdo_write 3 1017 0 2 100"),
    ]),
    # broadcast reset node (000#8100) while everything runs; CANopenNode's master
    # obeys it too, powers up again and then does its usual 000#8200 + configuration
    "reset_node_all": Scenario(10.0, [
        *boot(),
        ctl(4.0, "master", "nmt 81 0"),
    ]),
    # guarded node 4 power-cycled (off 0.3 s): it comes back with its power-on
    # 1017h = 1000 ms (guarding slave disabled) while the master keeps polling;
    # the master application re-configures it 1.7 s later
    "guarded_power_cycle": Scenario(10.0, [
        *boot(),
        kill(4.0, "s4"),
        spawn(4.3, "s4", slave(4)),
        ctl(6.0, "master", "config 4"),
    ]),
    # as guarded_power_cycle, but node 4 has its guarding configuration stored
    # (power-on 1017h = 0, 100Ch = 100 ms, 100Dh = 3): it answers the master's
    # requests right after its boot-up (toggle 0 again) and stays PRE-OPERATIONAL
    # until the master application re-configures and starts it 0.5 s later
    "guarded_power_cycle_stored": Scenario(10.0, [
        spawn(0.0, "s2", slave(2)),
        spawn(0.0, "s3", slave(3)),
        spawn(0.0, "s4", ["--node", "4", "--hb", "0", "--guard", "100:3"]),
        spawn(0.0, "master", MASTER),
        kill(4.0, "s4"),
        spawn(4.3, "s4", ["--node", "4", "--hb", "0", "--guard", "100:3"]),
        ctl(4.8, "master", "config 4"),
    ]),
    # SYNC producer on the master (50 ms), TPDO1 of nodes 2 and 3 set to
    # synchronous (type 1 / type 4) by SDO while OPERATIONAL; node 2 stopped
    # and started again
    "sync_pdo": Scenario(10.0, [
        spawn(0.0, "s2", slave(2)),
        spawn(0.0, "s3", slave(3)),
        spawn(0.0, "s4", slave(4)),
        spawn(0.0, "master", [*MASTER, "--sync-us", "50000"]),
        ctl(1.0, "master", "sdo_write 2 1800 2 1 1"),
        ctl(1.0, "master", "sdo_write 3 1800 2 1 4"),
        ctl(4.0, "master", "nmt 02 2"),
        ctl(6.0, "master", "nmt 01 2"),
    ]),
    # ---- SYNC and EMCY faults raised by the stack itself (sync_emcy/) --------------
    # node 2 produces SYNC every 20 ms (1005h bit 30, 1006h at power-on); the master
    # writes 1006h = 20 ms to nodes 3 and 4 by SDO, so their SYNC consumer timeout runs
    # (armed by the first SYNC, fires after 1.5 x 1006h). The master stops node 2 at
    # 4.0: the consumers raise EMCY 8100h (error bit 18h) and drop to PRE-OPERATIONAL
    # (CO_NMT_ERR_ON_ERR_REG, communication bit). Node 2 started again at 6.0 (SYNC
    # back: the consumers reset their EMCY, stay pre-operational), nodes 3 and 4 at 7.0
    "sync_producer_stopped": Scenario(10.0, [
        spawn(0.0, "s2", slave(2, "--sync-us", "20000")),
        spawn(0.0, "s3", slave(3)),
        spawn(0.0, "s4", slave(4)),
        spawn(0.0, "master", MASTER),
        ctl(1.0, "master", "sdo_write 3 1006 0 4 20000"),
        ctl(1.0, "master", "sdo_write 4 1006 0 4 20000"),
        ctl(4.0, "master", "nmt 02 2"),
        ctl(6.0, "master", "nmt 01 2"),
        ctl(7.0, "master", "nmt 01 3"),
        ctl(7.0, "master", "nmt 01 4"),
        ctl(9.8, "s2", "status"),
        ctl(9.8, "s3", "status"),
        ctl(9.8, "s4", "status"),
    ]),
    # the master produces SYNC every 20 ms with a counter (1019h = 4 at power-on on
    # every node: CANopenNode consumers drop a SYNC whose length does not fit their
    # 1019h); the slaves consume it with 1006h = 20 ms (power-on). Healthy.
    "sync_counter": Scenario(10.0, [
        spawn(0.0, "s2", slave(2, *SYNC_CONS)),
        spawn(0.0, "s3", slave(3, *SYNC_CONS)),
        spawn(0.0, "s4", slave(4, *SYNC_CONS)),
        spawn(0.0, "master", [*MASTER, "--sync-us", "20000", "--sync-ovf", "4"]),
        ctl(9.8, "s2", "status"),
        ctl(9.8, "s3", "status"),
        ctl(9.8, "s4", "status"),
    ]),
    # as sync_counter, the master on the patched stack (sync_skip.patch): once, from its
    # 300th SYNC on, it skips counter value 2 (1, 3 instead of 1, 2, 3)
    "sync_counter_skip": Scenario(10.0, [
        spawn(0.0, "s2", slave(2, *SYNC_CONS)),
        spawn(0.0, "s3", slave(3, *SYNC_CONS)),
        spawn(0.0, "s4", slave(4, *SYNC_CONS)),
        spawn(0.0, "master", [*MASTER, "--sync-us", "20000", "--sync-ovf", "4"], "dev_syncskip"),
        ctl(9.8, "s2", "status"),
        ctl(9.8, "s3", "status"),
        ctl(9.8, "s4", "status"),
    ]),
    # the master produces SYNC every 20 ms without a counter (its 1019h = 0 at power-on);
    # at 1.0 it writes 1019h = 4 and then 1006h = 20 ms to nodes 2 and 3 by SDO (a
    # consumer accepts 1019h only while its 1006h = 0): their SYNC consumers now expect
    # one data byte, so every SYNC of length 0 is a wrong-length SYNC to them (EMCY 8240h,
    # the SYNC dropped) and their SYNC timeout runs out (8100h). Node 4 stays as it was
    "sync_length": Scenario(10.0, [
        spawn(0.0, "s2", slave(2)),
        spawn(0.0, "s3", slave(3)),
        spawn(0.0, "s4", slave(4)),
        spawn(0.0, "master", [*MASTER, "--sync-us", "20000"]),
        ctl(1.0, "master", "sdo_write 2 1019 0 1 4"),
        ctl(1.0, "master", "sdo_write 2 1006 0 4 20000"),
        ctl(1.0, "master", "sdo_write 3 1019 0 1 4"),
        ctl(1.0, "master", "sdo_write 3 1006 0 4 20000"),
        ctl(9.8, "s2", "status"),
        ctl(9.8, "s3", "status"),
        ctl(9.8, "s4", "status"),
    ]),
    # the master's 1006h asks for a SYNC every 5.3 ms, but its application calls
    # CO_process() about once a millisecond (dev.c's loop) and the stack sends the SYNC in
    # the first call at or past 1006h, then counts from 0 again: the bus sees a SYNC
    # every 6 calls, about every 6.2 ms
    "sync_period_fast": Scenario(6.0, [
        spawn(0.0, "s2", slave(2)),
        spawn(0.0, "s3", slave(3)),
        spawn(0.0, "s4", slave(4)),
        spawn(0.0, "master", [*MASTER, "--sync-us", "5300"]),
    ]),
    # the master writes reserved PDO transmission types by SDO: 1800h:02 = 245 to node 2
    # (TPDO1; 241-251 are reserved) at 2.0 and 1400h:02 = 250 to node 3 (RPDO1; 241-253)
    # at 3.0. CANopenNode refuses both (SDO abort)
    "reserved_type": Scenario(6.0, [
        spawn(0.0, "s2", slave(2)),
        spawn(0.0, "s3", slave(3)),
        spawn(0.0, "s4", slave(4)),
        spawn(0.0, "master", MASTER),
        ctl(2.0, "master", "sdo_write 2 1800 2 1 245"),
        ctl(3.0, "master", "sdo_write 3 1400 2 1 250"),
    ]),
    # EMCY inhibit time: node 3 has 1015h = 50 ms at power-on, node 2 gets 1015h = 30 ms
    # by SDO at 2.0. Node 3's application raises three manufacturer errors at once at
    # 3.0 (error bits 40h-42h: error register bit 7) and resets them 20 ms later: the
    # stack queues the six EMCYs and sends them 50 ms apart. Node 2's application
    # raises a manufacturer error (42h) and a generic-critical one (2Ch: register bit
    # 0, in its NMT control mask) at 5.0 and resets the manufacturer one 10 ms later:
    # node 2 drops to PRE-OPERATIONAL, three EMCYs 30 ms apart, and 2Ch stays active
    "emcy_inhibit": Scenario(10.0, [
        spawn(0.0, "s2", slave(2)),
        spawn(0.0, "s3", slave(3, "--emcy-inhibit", "500")),
        spawn(0.0, "s4", slave(4)),
        spawn(0.0, "master", MASTER),
        ctl(2.0, "master", "sdo_write 2 1015 0 2 300"),
        ctl(3.0, "s3", "err_set 40 5000 1"),
        ctl(3.0, "s3", "err_set 41 6100 2"),
        ctl(3.0, "s3", "err_set 42 FF00 3"),
        ctl(3.02, "s3", "err_reset 40 0"),
        ctl(3.02, "s3", "err_reset 41 0"),
        ctl(3.02, "s3", "err_reset 42 0"),
        ctl(5.0, "s2", "err_set 42 FF00 4"),
        ctl(5.0, "s2", "err_set 2C 6100 5"),
        ctl(5.01, "s2", "err_reset 42 0"),
        ctl(9.8, "s2", "status"),
        ctl(9.8, "s3", "status"),
    ]),
    # ---- PDO timing faults raised or shown by the stack itself (pdo/) ---------------
    # PDO linking: node 2's TPDO1 (182h, 2000h, type 254, event timer 100 ms) is node 3's
    # RPDO1 (1400h = 182h, type 254, event timer = deadline 250 ms, 1600h maps 2001h). The
    # master stops node 2 at 4.0: node 3's RPDO timeout fires (EMCY 8250h, error bit 17h,
    # register 10h) and node 3 drops to PRE-OPERATIONAL (CO_NMT_ERR_ON_ERR_REG). Node 2
    # started again at 6.0, node 3 at 7.0
    "rpdo_producer_stopped": Scenario(10.0, [
        spawn(0.0, "s2", slave(2, "--tpdo1", "254:0:100")),
        spawn(0.0, "s3", slave(3, "--rpdo1", "182:254:250:20010020")),
        spawn(0.0, "s4", slave(4)),
        spawn(0.0, "master", MASTER),
        ctl(4.0, "master", "nmt 02 2"),
        ctl(6.0, "master", "nmt 01 2"),
        ctl(7.0, "master", "nmt 01 3"),
        *[ctl(9.8, d, "status") for d in ("s2", "s3", "s4")],
    ]),
    # as rpdo_producer_stopped with node 3's deadline 300 ms = 3 x node 2's event timer and
    # 3 x node 3's own heartbeat period (both run in phase from the start at 0.15 s): the
    # RPDO timeout usually falls in the CO_process() call in which node 3's heartbeat is
    # due, and the stack sends that heartbeat (still OPERATIONAL) after its EMCY 8250h
    "rpdo_timeout_stale_heartbeat": Scenario(10.0, [
        spawn(0.0, "s2", slave(2, "--tpdo1", "254:0:100")),
        spawn(0.0, "s3", slave(3, "--rpdo1", "182:254:300:20010020")),
        spawn(0.0, "s4", slave(4)),
        spawn(0.0, "master", MASTER),
        ctl(4.0, "master", "nmt 02 2"),
        ctl(6.0, "master", "nmt 01 2"),
        ctl(7.0, "master", "nmt 01 3"),
        *[ctl(9.8, d, "status") for d in ("s2", "s3", "s4")],
    ]),
    # event-driven TPDOs, healthy: node 2 type 254, inhibit 10 ms, event timer 100 ms; node 3
    # type 255, inhibit 20 ms, event timer 250 ms; node 4 type 254 without inhibit time or
    # event timer (sent only on request). The applications ask for their TPDO in bursts
    # faster than the inhibit time (the stack holds the frames back) and slower than it
    "tpdo_event_timer": Scenario(10.0, [
        spawn(0.0, "s2", slave(2, "--tpdo1", "254:100:100")),
        spawn(0.0, "s3", slave(3, "--tpdo1", "255:200:250")),
        spawn(0.0, "s4", slave(4, "--tpdo1", "254:0:0")),
        spawn(0.0, "master", MASTER),
        ctl(2.0, "s4", "tpdo_req 1 0"),
        ctl(3.0, "s2", "tpdo_req 20 2"),
        ctl(4.0, "s4", "tpdo_req 3 300"),
        ctl(5.0, "s3", "tpdo_req 10 5"),
        ctl(7.0, "s2", "tpdo_req 5 30"),
        *[ctl(9.8, d, "status") for d in ("s2", "s3", "s4")],
    ]),
    # as tpdo_event_timer's node 2 (inhibit 10 ms, event timer 100 ms), on the patched stack
    # (tpdo_inhibit.patch): the first four times a send request finds the inhibit time
    # running, the TPDO goes out at once. 3.0: five requests 1 ms apart (the bug: five
    # TPDOs about 1 ms apart); 6.0: the same, the bug spent (the stack holds them to 10 ms)
    "tpdo_inhibit_bypass": Scenario(10.0, [
        spawn(0.0, "s2", slave(2, "--tpdo1", "254:100:100"), "dev_inhibit"),
        spawn(0.0, "s3", slave(3)),
        spawn(0.0, "s4", slave(4)),
        spawn(0.0, "master", MASTER),
        ctl(3.0, "s2", "tpdo_req 5 1"),
        ctl(6.0, "s2", "tpdo_req 5 1"),
        *[ctl(9.8, d, "status") for d in ("s2", "s3", "s4")],
    ]),
    # node 2's TPDO1 (182h, 4 bytes: 2000h) is RPDO1 of node 3, which maps 8 bytes (a dummy
    # UNSIGNED32, then 2001h: EMCY 8210h, frames discarded) and of node 4, which maps 2
    # bytes (16 bits of 2001h: EMCY 8220h, frames processed). 5.0: the master fixes node 3's
    # mapping by SDO (RPDO invalid, 1600h = 2001h 32 bit, valid again): node 3 resets its
    # error; node 4 stays in error
    "rpdo_length": Scenario(10.0, [
        spawn(0.0, "s2", slave(2, "--tpdo1", "254:0:100")),
        spawn(0.0, "s3", slave(3, "--rpdo1", "182:254:0:00070020,20010020")),
        spawn(0.0, "s4", slave(4, "--rpdo1", "182:254:0:20010010")),
        spawn(0.0, "master", MASTER),
        ctl(5.0, "master", "sdo_write 3 1400 1 4 2147484034"),  # 80000182h: RPDO1 not valid
        ctl(5.0, "master", "sdo_write 3 1600 0 1 0"),
        ctl(5.0, "master", "sdo_write 3 1600 1 4 536936480"),  # 20010020h
        ctl(5.0, "master", "sdo_write 3 1600 0 1 1"),
        ctl(5.0, "master", "sdo_write 3 1400 1 4 386"),  # 00000182h: valid again
        *[ctl(9.8, d, "status") for d in ("s2", "s3", "s4")],
    ]),
    # synchronous TPDOs, healthy: the master produces SYNC every 20 ms (no counter); node 2's
    # TPDO1 type 1 (every SYNC), node 3's type 4 (every 4th), node 4's type 0 (acyclic: at
    # the SYNC after an application request). Node 2 stopped at 4.0, started at 6.0
    "sync_tpdo": Scenario(10.0, [
        spawn(0.0, "s2", slave(2, "--tpdo1", "1:0:0")),
        spawn(0.0, "s3", slave(3, "--tpdo1", "4:0:0")),
        spawn(0.0, "s4", slave(4, "--tpdo1", "0:0:0")),
        spawn(0.0, "master", [*MASTER, "--sync-us", "20000"]),
        ctl(3.0, "s4", "tpdo_req 10 1"),
        ctl(4.0, "master", "nmt 02 2"),
        ctl(5.0, "s4", "tpdo_req 10 30"),
        ctl(6.0, "master", "nmt 01 2"),
        *[ctl(9.8, d, "status") for d in ("s2", "s3", "s4")],
    ]),
    # as sync_tpdo's node 2 (TPDO1 type 1, SYNC every 20 ms from the master), with a synchronous
    # window 1007h = 10 ms at power-on, on the patched stack (tpdo_late.patch): from the 100th
    # SYNC on which its TPDO is due, every 50th, three times, the stack holds the TPDO back and
    # sends it 4 ms after the window has passed (14 ms after its SYNC)
    "tpdo_late": Scenario(10.0, [
        spawn(0.0, "s2", slave(2, "--tpdo1", "1:0:0", "--sync-window-us", "10000"), "dev_late"),
        spawn(0.0, "s3", slave(3)),
        spawn(0.0, "s4", slave(4)),
        spawn(0.0, "master", [*MASTER, "--sync-us", "20000"]),
        *[ctl(9.8, d, "status") for d in ("s2", "s3", "s4")],
    ]),
    # as tpdo_late, but node 2's power-on 1007h is 0: the master writes 1007h = 10 ms to node
    # 2 by SDO at 1.0 (CANopenNode takes it at once: CO_SYNC reads 1007h from the OD at every
    # SYNC), so the window the patched stack passes is one written in the trace
    "tpdo_late_written": Scenario(10.0, [
        spawn(0.0, "s2", slave(2, "--tpdo1", "1:0:0"), "dev_late"),
        spawn(0.0, "s3", slave(3)),
        spawn(0.0, "s4", slave(4)),
        spawn(0.0, "master", [*MASTER, "--sync-us", "20000"]),
        ctl(1.0, "master", "sdo_write 2 1007 0 4 10000"),
        *[ctl(9.8, d, "status") for d in ("s2", "s3", "s4")],
    ]),
    # node 3 on the patched stack (emcy_short.patch): the first two EMCYs of its program run go
    # out with DLC 4. Its application raises a manufacturer error (bit 40h, 5000h) at 3.0 and
    # resets it at 3.5 (both EMCYs short), then the same again at 5.0 and 5.5 (DLC 8)
    "emcy_short": Scenario(10.0, [
        spawn(0.0, "s2", slave(2)),
        spawn(0.0, "s3", slave(3), "dev_emcyshort"),
        spawn(0.0, "s4", slave(4)),
        spawn(0.0, "master", MASTER),
        ctl(3.0, "s3", "err_set 40 5000 1"),
        ctl(3.5, "s3", "err_reset 40 0"),
        ctl(5.0, "s3", "err_set 40 5000 2"),
        ctl(5.5, "s3", "err_reset 40 0"),
        *[ctl(9.8, d, "status") for d in ("s2", "s3", "s4")],
    ]),
}


# LSS recordings (lss/): CANopenNode's LSS master (lss_dev --master) runs a script of LSS
# master calls; slaves are lss_dev LSS slaves, non-configured (node-ID 255) or configured
ID_A = "300:4644:0:1"
ID_B = "300:4644:0:2"
ID_C = "300:4644:0:4"
ID_D = "19:1:0:1"


def lss_master(script: str, timeout_ms: int = 100) -> list[str]:
    """Node 1 with no heartbeat of its own; the script after 300 ms, with the master's
    response timeout (CO_LSSmaster_changeTimeout; CANopenNode's master waits it out after
    every fastscan request, answered or not, so the fastscans use 25 ms)."""
    return ["--node", "1", "--hb", "0", "--master", "--script",
            f"wait 300;timeout {timeout_ms};" + script]


def lss_slave(identity: str, node: int = 255, *extra: str) -> list[str]:
    return ["--node", str(node), "--hb", "1000", "--identity", identity, *extra]


LSS_SCENARIOS: dict[str, Scenario] = {
    "lss_configure_store": Scenario(3.0, [
        spawn(0.0, "sA", lss_slave(ID_A, 255, "--store"), "lss_dev"),
        spawn(0.0, "master", lss_master(f"select {ID_A};inquire_node;node 5;store;deselect"),
              "lss_dev"),
    ]),
    "lss_fastscan_one": Scenario(6.0, [
        spawn(0.0, "sA", lss_slave(ID_A, 255, "--store"), "lss_dev"),
        spawn(0.0, "master", lss_master("fastscan;node 6;store;deselect", 25), "lss_dev"),
    ]),
    "lss_fastscan_two": Scenario(11.0, [
        spawn(0.0, "sA", lss_slave(ID_A, 255, "--store"), "lss_dev"),
        spawn(0.0, "sB", lss_slave(ID_B, 255, "--store"), "lss_dev"),
        spawn(0.0, "master", lss_master(
            "fastscan;node 6;store;deselect;wait 300;fastscan;node 7;store;deselect;wait 300;"
            "fastscan", 25), "lss_dev"),
    ]),
    "lss_fastscan_nobody": Scenario(3.0, [
        spawn(0.0, "sC", lss_slave(ID_C, 3, "--store"), "lss_dev"),
        spawn(0.0, "master", lss_master("fastscan", 25), "lss_dev"),
    ]),
    "lss_selective_nobody": Scenario(3.0, [
        spawn(0.0, "sA", lss_slave(ID_A, 255, "--store"), "lss_dev"),
        spawn(0.0, "master", lss_master("select 300:4644:0:9;wait 1500;deselect"), "lss_dev"),
    ]),
    "lss_store_error": Scenario(3.0, [
        spawn(0.0, "sA", lss_slave(ID_A), "lss_dev"),
        spawn(0.0, "master", lss_master(f"select {ID_A};node 5;store;deselect"), "lss_dev"),
    ]),
    "lss_two_in_configuration": Scenario(2.0, [
        spawn(0.0, "sA", lss_slave(ID_A), "lss_dev"),
        spawn(0.0, "sD", lss_slave(ID_D), "lss_dev"),
        spawn(0.0, "master", lss_master("select_all;inquire_vendor;wait 200;deselect"),
              "lss_dev"),
    ]),
    "lss_bitrate_silent": Scenario(3.0, [
        spawn(0.0, "sA", lss_slave(ID_A), "lss_dev"),
        spawn(0.0, "master", lss_master(f"select {ID_A};bitrate 125;wait 1500;deselect"),
              "lss_dev"),
    ]),
    "lss_not_adopted": Scenario(8.0, [
        spawn(0.0, "sC", lss_slave(ID_C, 3), "lss_dev"),
        spawn(0.0, "master", lss_master(
            f"select {ID_C};inquire_node;node 8;deselect;wait 1200;nmt 82 0"), "lss_dev"),
        kill(1.0, "sC"),
        spawn(1.1, "sC", lss_slave(ID_C, 3), "lss_dev"),
    ]),
}
LELY_EDS = "../lely/lss/lss.eds"  # from this folder, where hub.py runs the devices


def lely_master(script: str) -> list[str]:
    """Lely's NMT and LSS master (samples/lely/lss/lely_lss.c), node 1, running the script
    from its LSS request function at its communication reset."""
    return ["--node", "1", "--eds", LELY_EDS, "--master", "--script", script]


LSS_SCENARIOS.update({
    "lely_selective_nobody": Scenario(2.0, [
        spawn(0.0, "sA", lss_slave(ID_A, 255, "--store"), "lss_dev"),
        spawn(0.3, "master", lely_master("select 300:4644:0:9;waiting"), "lely_lss"),
    ]),
    "lely_fastscan": Scenario(16.0, [
        spawn(0.0, "sA", lss_slave(ID_A, 255, "--store"), "lss_dev"),
        spawn(0.3, "master", lely_master("fastscan;node 5;store;waiting"), "lely_lss"),
    ]),
    "lely_configure_after_waiting": Scenario(2.0, [
        spawn(0.0, "sA", lss_slave(ID_A, 255, "--store"), "lss_dev"),
        spawn(0.3, "master", lely_master(f"select {ID_A};waiting;node 5"), "lely_lss"),
    ]),
    "lely_fastscan_configured": Scenario(16.0, [
        spawn(0.0, "sL", ["--node", "3", "--eds", LELY_EDS, "--identity", ID_C], "lely_lss"),
        spawn(0.3, "master", lely_master("fastscan;inquire_node;waiting"), "lely_lss"),
    ]),
})
SCENARIOS.update(LSS_SCENARIOS)


def fmt_frame(ts_us: int, can_id: int, rtr: int, dlc: int, data: bytes) -> str:
    sec, usec = divmod(ts_us, 1000000)
    payload = "R" + (f"{dlc:X}" if dlc else "") if rtr else data[:dlc].hex().upper()
    return f"({sec}.{usec:06d}) can0 {can_id:03X}#{payload}\n"


class Hub:
    """The bus: the hub socket, the devices and the log of one scenario run."""

    def __init__(self, tmp: str, bindir: str, sock: socket.socket, events: TextIO,
                 log: TextIO) -> None:
        self.tmp = tmp
        self.bindir = bindir
        self.sock = sock
        self.events = events
        self.log = log
        self.devs: dict[str, Device] = {}
        self.addr2name: dict[str, str] = {}
        self.stats: Stats = {"logged": 0, "dropped_unplugged": 0, "delivered": 0}
        self.t0 = time.monotonic()

    def t_rel(self) -> float:
        return time.monotonic() - self.t0

    def note(self, msg: str) -> None:
        self.events.write(f"# hub t={self.t_rel():.6f} {msg}\n")
        self.events.flush()

    def do(self, action: Action) -> None:
        kind, dev = action.kind, action.dev
        if kind == "spawn":
            binary = os.path.join(self.bindir, action.binary)
            addr = os.path.join(self.tmp, f"dev-{dev}.sock")
            proc = subprocess.Popen([binary, "--hub", self.tmp, "--name", dev, *action.args],
                                    stderr=self.events, stdout=subprocess.DEVNULL)
            self.devs[dev] = Device(proc, addr)
            self.addr2name[addr] = dev
            self.note(f"spawn {dev}: {os.path.basename(binary)} {' '.join(action.args)}")
        elif kind == "kill":
            self.devs[dev].proc.kill()
            self.devs[dev].proc.wait()
            self.devs[dev].plugged = False
            self.note(f"power off {dev}")
        elif kind == "unplug":
            self.devs[dev].plugged = False
            self.note(f"unplug {dev}")
        elif kind == "plug":
            self.devs[dev].plugged = True
            self.note(f"plug {dev}")
        elif kind == "ctl":
            self.note(f"control {dev}: {action.cmd}")
            try:
                self.sock.sendto(b"C" + action.cmd.encode(), self.devs[dev].addr)
            except OSError as e:
                self.note(f"control to {dev} failed: {e}")

    def play(self, duration: float, actions: list[Action]) -> None:
        """Run the actions (sorted by time) and carry the bus until `duration`."""
        self.t0 = time.monotonic()
        i = 0
        while True:
            now = self.t_rel()
            while i < len(actions) and actions[i].t <= now:
                self.do(actions[i])
                i += 1
            if now >= duration:
                break
            nxt = actions[i].t if i < len(actions) else duration
            r, _, _ = select.select([self.sock], [], [], max(0.0, min(nxt, duration) - now))
            if r:
                self.drain()

    def drain(self) -> None:
        """Take every datagram waiting on the hub socket."""
        while True:
            try:
                data, addr = self.sock.recvfrom(256, socket.MSG_DONTWAIT)
            except BlockingIOError:
                break
            self.receive(data, addr, time.time_ns() // 1000)

    def receive(self, data: bytes, addr: str, ts_us: int) -> None:
        """Log one datagram as a bus frame and deliver it to the other plugged devices."""
        sender = self.addr2name.get(addr)
        if sender is None or len(data) != FRAME.size:
            self.note(f"datagram from unknown sender {addr!r}")
            return
        typ, rtr, dlc, _, can_id, payload = FRAME.unpack(data)
        if typ != ord("F"):
            return  # hello
        if not self.devs[sender].plugged:
            self.stats["dropped_unplugged"] += 1
            return
        self.log.write(fmt_frame(ts_us, can_id, rtr, dlc, payload))
        self.stats["logged"] += 1
        for other, d in self.devs.items():
            if other == sender or not d.plugged:
                continue
            try:
                self.sock.sendto(data, d.addr)
                self.stats["delivered"] += 1
            except OSError as e:
                self.note(f"delivery to {other} failed: {e}")

    def power_off(self) -> None:
        for d in self.devs.values():
            d.proc.kill()
        for d in self.devs.values():
            d.proc.wait()


def run(name: str, out_path: str, bindir: str, events_path: str) -> Stats:
    duration, actions = SCENARIOS[name]
    actions = sorted(actions, key=lambda a: a.t)  # stable: same-time actions keep their order
    tmp = tempfile.mkdtemp(prefix="cohub-")
    hub_path = os.path.join(tmp, "hub.sock")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(hub_path)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    with open(events_path, "w") as events:
        with open(out_path, "w") as log:
            hub = Hub(tmp, bindir, sock, events, log)
            hub.play(duration, actions)
            hub.power_off()
        stats = hub.stats
        hub.note(f"end: logged {stats['logged']} frames, {stats['dropped_unplugged']} frames "
                 f"of unplugged devices not put on the bus, {stats['delivered']} deliveries")
    sock.close()
    for f in os.listdir(tmp):
        os.unlink(os.path.join(tmp, f))
    os.rmdir(tmp)
    return stats


def main(argv: list[str]) -> int:
    if len(argv) < 3 or argv[1] not in SCENARIOS:
        print((__doc__ or "").split("\n\n")[0])
        print("scenarios: " + " ".join(SCENARIOS))
        return 2
    bindir = "/work/build/canopennode/bin"
    events = os.path.splitext(argv[2])[0] + ".events"
    rest = argv[3:]
    while rest:
        if rest[0] == "--bin":
            bindir = rest[1]
        elif rest[0] == "--events":
            events = rest[1]
        else:
            print(f"unknown option {rest[0]}")
            return 2
        rest = rest[2:]
    stats = run(argv[1], argv[2], bindir, events)
    print(f"{argv[1]}: {stats['logged']} frames -> {argv[2]}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
