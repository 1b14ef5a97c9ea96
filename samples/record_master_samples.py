#!/usr/bin/env python3
"""Record CANopen traces with a CiA 302-style NMT master built on python-canopen.

Companion of ``record_samples.py`` (whose ``Bench``, ``build_od`` and PDO
scheduler this script imports). There the master is a bare
``canopen.Network`` that sends commands but is no node. Here the master is
**node 1**, a ``canopen.LocalNode`` with its own object dictionary on the
master's ``canopen.Network``, and its application code behaves like a
CiA 302 NMT master:

1. power-on: its own boot-up ``701#00``; canopen then starts its heartbeat
   producer (1017h = 200 ms) with a first ``701#7F`` at once (python-can's
   cyclic task sends its first frame immediately);
2. 50 ms later NMT *reset communication, all nodes* ``000#8200``. The master
   does not receive its own frame (no CAN controller does; the virtual
   buses here do not either), so it does not obey it;
3. "boot slave" for every slave whose boot-up it receives: SDO upload of
   1000h (device type) and 1018h:01 (vendor-ID), SDO download of 1016h:01 =
   0001_01F4h (the slave consumes the master's heartbeat, 500 ms) and 1017h
   = 100 (the slaves' power-on 1017h is 0: they are silent after their
   boot-up until this write);
4. once the mandatory slaves 2, 3, 4 are configured: the master starts
   itself (its next heartbeat says 05h) and sends *start all* ``000#0100``;
5. heartbeat consumer, in application code (CiA 302-2 error control): the
   master's own 1016h holds 250 ms per slave. Monitoring of a slave starts at
   its first heartbeat after configuration and stops while it boots. On a
   heartbeat event of slave N the master sends *reset node N* ``000#81NN``
   and waits for N's boot-up (boot time 2 s, then it resets again). A
   heartbeat of N while it waits ("sign of life without boot-up": N did not
   get the reset) makes it send the reset again at once. Every boot-up of a
   slave (after a reset or spontaneous) starts "boot slave" again, and once
   the network runs the master starts N with ``000#01NN``.

The slaves are ``canopen.LocalNode`` s built by :meth:`MasterBench.add_slave`.
Unlike canopen's own handling (a received reset leaves a LocalNode in 00h
forever, see ``record_samples.py``), these slaves **reboot properly**: on a
reset node/communication addressed to them they leave OPERATIONAL at once
(no heartbeat, no PDO), and after a reset time of 30/40/50 ms (node 2/3/4)
they restore their power-on communication values (1016h, 1017h = 0), send
the boot-up 70N#00 and are PRE-OPERATIONAL and silent until the master
writes 1017h again. A slave that is "unplugged" or not yet powered neither
sends nor receives anything. canopen's LocalNode has no heartbeat consumer:
a written 1016h is only stored, so a slave does not react to the loss of
the master's heartbeat.

TPDO1 (180h+N, every 50 ms) comes from ``record_samples.Bench``'s scheduler,
which sends only while the slave is OPERATIONAL.

Every scenario is recorded by a separate python-can virtual bus and written
with ``can.CanutilsLogWriter`` as ``samples/canopen_master/<name>.log``
(candump ``-L``, interface ``can0``). The script reads each file back with
``can.LogReader`` and checks at frame level: frames sent == frames recorded,
no duplicates, the master's start-up sequence, and the scenario's intended
behaviour (see :func:`verify`). ``README.md`` in the output folder lists what
happens and the findings a checker should report (SPEC section 3).

Usage::

    python samples/record_master_samples.py [--outdir DIR] [--only NAME ...]
    python samples/record_master_samples.py --check-only   # verify existing logs

Needs ``python-can`` 4.6.1 and ``canopen`` 2.4.1.
"""

from __future__ import annotations

import argparse
import logging
import queue
import statistics
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from itertools import pairwise
from pathlib import Path

import can
import canopen
from canopen import objectdictionary as od_mod

sys.path.insert(0, str(Path(__file__).resolve().parent))
from canopen.sdo.base import SdoArray, SdoRecord, SdoVariable
from record_samples import (
    CS_PREOP,
    CS_RESET_COMM,
    CS_RESET_NODE,
    CS_START,
    LOG_CHANNEL,
    VENDOR_ID,
    Bench,
    Slave,
    _var,
    build_od,
    read_back,
    summarize,
)

MASTER_ID = 1
SLAVES = (2, 3, 4)


def _sdo(node: canopen.LocalNode | canopen.RemoteNode, index: int,
         subindex: int | None = None) -> SdoVariable:
    """One variable of a node's object dictionary, through its SDO server or client."""
    obj = node.sdo[index]
    if subindex is not None:
        assert isinstance(obj, (SdoArray, SdoRecord))
        obj = obj[subindex]
    assert isinstance(obj, SdoVariable)
    return obj


def _raw(node: canopen.LocalNode | canopen.RemoteNode, index: int,
         subindex: int | None = None) -> int:
    """The value of an integer variable (`.raw`)."""
    value = _sdo(node, index, subindex).raw
    assert isinstance(value, int)
    return value
MASTER_HB_MS = 200  # master's own 1017h
SLAVE_HB_MS = 100  # 1017h the master writes to each slave
CONSUMER_MS = 250  # master's 1016h entry per slave (2.5 x 100 ms)
SLAVE_CONSUMER_MS = 500  # 1016h:01 the master writes to each slave (watches node 1)
BOOT_TIME_S = 2.0  # master waits this long for a boot-up after a reset (1F89h)
RESET_DELAY = {2: 0.030, 3: 0.040, 4: 0.050}  # slave reset time (s) before its boot-up
DEVICE_TYPE = 0x00000191
PERIOD_CHANGE_MS = 300  # period_change: new 1017h of node 3
CS_NAMES = {0x01: "start", 0x02: "stop", 0x80: "pre-op", 0x81: "reset node", 0x82: "reset comm"}


# --------------------------------------------------------------------------
# Slaves that reboot properly
# --------------------------------------------------------------------------


@dataclass
class RebootSlave(Slave):
    powered: bool = False
    reset_delay: float = 0.040
    timers: list[threading.Timer] = field(default_factory=list)
    log: list[tuple[float, str]] = field(default_factory=list)  # (t, event) for the notes


class MasterBench(Bench):
    """``record_samples.Bench`` with rebooting slaves and a CiA 302 master."""

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.cia302: Cia302Master | None = None

    def rel(self) -> float:
        return time.perf_counter() - self.t0

    def add_slave(self, node_id: int, **_ignored: object) -> RebootSlave:  # type: ignore[override]
        network = canopen.Network()
        network.NOTIFIER_CYCLE = 0.1
        node = canopen.LocalNode(node_id, build_od(node_id, 0, consumer_entries=1))
        slave = RebootSlave(node_id, node, network, silent=True)
        slave.reset_delay = RESET_DELAY.get(node_id, 0.040)
        original: Callable[[int, bytearray, float], None] = node.nmt.on_command

        def on_command(can_id: int, data: bytearray, timestamp: float) -> None:
            addressed = len(data) >= 2 and data[1] in (0, node_id)
            if slave.silent or not slave.powered:
                pass  # unplugged / not powered: the frame never reaches it
            elif addressed and data[0] in (CS_RESET_NODE, CS_RESET_COMM):
                self._enter_reset(slave, f"NMT {data[0]:02X} {data[1]:02X}")
            else:
                original(can_id, data, timestamp)
            with slave.cond:
                slave.processed += 1
                slave.cond.notify_all()

        node.nmt.on_command = on_command  # type: ignore[method-assign]
        network.add_node(node)
        network.connect(interface="virtual", channel=self.vchannel, receive_own_messages=False)
        self._count_sends(network.bus, f"node{node_id}")
        node.tpdo.read(from_od=True)
        self.slaves[node_id] = slave
        self.master.add_node(node_id, build_od(node_id, 0, consumer_entries=1))
        return slave

    def _enter_reset(self, slave: RebootSlave, why: str) -> None:
        """Leave the current state at once (no heartbeat, no PDO), boot-up
        after the slave's reset time."""
        slave.node.nmt.stop_heartbeat()
        slave.node.nmt._state = 0  # INITIALISING: the PDO scheduler skips it
        slave.log.append((self.rel(), f"reset ({why})"))
        timer = threading.Timer(slave.reset_delay, self._boot, (slave,))
        slave.timers.append(timer)
        timer.start()

    def _boot(self, slave: RebootSlave) -> None:
        """Reset communication done: power-on values, boot-up, PRE-OPERATIONAL."""
        if self._stop.is_set() or slave.silent:
            return
        node = slave.node
        for index in (0x1016, 0x1017):  # communication parameters: power-on values
            node.data_store.pop(index, None)
        slave.counter = 0
        node.nmt.state = "INITIALISING"  # canopen sends 70N#00
        node.nmt.state = "PRE-OPERATIONAL"  # 1017h = 0: no heartbeat task
        slave.log.append((self.rel(), "boot-up"))

    def reboot_slave(self, node_id: int) -> RebootSlave:
        slave = self.slaves[node_id]
        assert isinstance(slave, RebootSlave)
        return slave

    def power_on(self, node_id: int) -> None:
        slave = self.reboot_slave(node_id)
        slave.powered, slave.silent = True, False
        self._boot(slave)

    def spontaneous_reboot(self, node_id: int) -> None:
        """Watchdog reset of the slave's application: no NMT command."""
        with self.pdo_lock:
            self._enter_reset(self.reboot_slave(node_id), "watchdog")

    def unplug(self, node_id: int) -> None:
        slave = self.reboot_slave(node_id)
        with self.pdo_lock:
            slave.silent = True
            slave.node.nmt.stop_heartbeat()
        slave.log.append((self.rel(), "unplugged"))

    def plug_in(self, node_id: int) -> None:
        """Back on the bus, still in the state it had; its heartbeat task
        restarts with the 1017h it holds (first frame at once)."""
        slave = self.reboot_slave(node_id)
        with self.pdo_lock:
            slave.silent = False
            slave.node.nmt.start_heartbeat(_raw(slave.node, 0x1017))
        slave.log.append((self.rel(), f"plugged in, state {slave.node.nmt.state}"))

    def finish(self) -> list[can.Message]:
        if self.cia302 is not None:
            self.cia302.stop()
        self._stop.set()
        for s in map(self.reboot_slave, self.slaves):
            for timer in s.timers:
                timer.cancel()
            for t, what in s.log:
                self.notes.append(f"node {s.node_id} @t0+{t:.3f}: {what}")
        if self.cia302 is not None:
            self.notes.extend(f"master @t0+{t:.3f}: {what}" for t, what in self.cia302.log)
        return super().finish()


# --------------------------------------------------------------------------
# The CiA 302-style master (node 1)
# --------------------------------------------------------------------------


def build_master_od() -> od_mod.ObjectDictionary:
    """Node 1: the slave dictionary of record_samples (1017h = 200) with a
    1016h of one entry per slave, plus 1F80h NMT start-up = 1 (NMT master)."""
    od = build_od(MASTER_ID, MASTER_HB_MS, consumer_entries=len(SLAVES))
    od.add_object(_var("NMT startup", 0x1F80, 0, od_mod.UNSIGNED32, 0x00000001, "rw"))
    return od


@dataclass
class Monitor:
    """Master-side state of one slave."""

    node_id: int
    enabled: bool = False  # consumer enabled (slave configured)
    armed: bool = False  # first heartbeat seen: timer running
    last: float = 0.0  # perf_counter of the last heartbeat
    awaiting_since: float | None = None  # reset sent, boot-up awaited
    alive_reported: bool = False
    booted: int = 0


class Cia302Master:
    def __init__(self, bench: MasterBench, slaves: tuple[int, ...] = SLAVES) -> None:
        self.b = bench
        bench.cia302 = self
        self.net = bench.master
        self.local = canopen.LocalNode(MASTER_ID, build_master_od())
        self.net.add_node(self.local)  # subscribes 000h and 601h: a real node
        for sub, nid in enumerate(slaves, start=1):
            _sdo(self.local, 0x1016, sub).raw = (nid << 16) | CONSUMER_MS  # local only
        self.mon = {nid: Monitor(nid) for nid in slaves}
        for nid in slaves:
            self.net.subscribe(0x700 + nid, self._on_error_control)
        self.events: queue.Queue[tuple[str, int, float]] = queue.Queue()
        self.log: list[tuple[float, str]] = []
        self.lock = threading.RLock()  # one master action at a time
        self.mon_lock = threading.Lock()
        self.operational = False
        self.powered = False  # before power-on the master receives nothing
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.started = threading.Event()  # network started (01 00 sent)

    # -- helpers -------------------------------------------------------------
    def note(self, what: str) -> None:
        self.log.append((self.b.rel(), what))

    def consumer_s(self, nid: int) -> float:
        for sub in range(1, len(self.mon) + 1):
            entry = _raw(self.local, 0x1016, sub)
            if entry >> 16 == nid:
                return (entry & 0xFFFF) / 1000.0
        raise KeyError(nid)

    def set_consumer(self, nid: int, ms: int) -> None:
        for sub in range(1, len(self.mon) + 1):
            if _raw(self.local, 0x1016, sub) >> 16 == nid:
                _sdo(self.local, 0x1016, sub).raw = (nid << 16) | ms
                self.note(f"own 1016h:{sub:02X} = node {nid}, {ms} ms")
                return
        raise KeyError(nid)

    def nmt(self, cs: int, nid: int) -> None:
        with self.lock:
            self.b.nmt(cs, nid)
            self.note(f"NMT {cs:02X} {nid:02X} ({CS_NAMES.get(cs, '?')})")

    # -- heartbeat consumer (runs in the master network's notifier thread) ---
    def _on_error_control(self, can_id: int, data: bytearray, timestamp: float) -> None:
        nid, now = can_id - 0x700, time.perf_counter()
        if not data or not self.powered:
            return
        m = self.mon[nid]
        with self.mon_lock:
            if data[0] == 0:  # boot-up: consumer off while the slave boots
                m.enabled = m.armed = False
                m.awaiting_since = None
                self.events.put(("bootup", nid, now))
            elif m.awaiting_since is not None:
                if not m.alive_reported:
                    m.alive_reported = True
                    self.events.put(("alive", nid, now))
            elif m.enabled:
                m.last, m.armed = now, True

    def _watch(self) -> None:
        while not self._stop.wait(0.002):
            now = time.perf_counter()
            with self.mon_lock:
                for m in self.mon.values():
                    if m.armed and now - m.last > self.consumer_s(m.node_id):
                        m.armed = m.enabled = False
                        self.events.put(("timeout", m.node_id, now))
                    elif m.awaiting_since is not None and now - m.awaiting_since > BOOT_TIME_S:
                        m.awaiting_since = now
                        self.events.put(("boot_timeout", m.node_id, now))

    # -- boot slave -----------------------------------------------------------
    def configure(self, nid: int) -> None:
        """CiA 302 'boot slave': identity check, then error control."""
        with self.lock:
            remote = self.net[nid]
            dev = _raw(remote, 0x1000)
            vendor = _raw(remote, 0x1018, 1)
            if dev != DEVICE_TYPE or vendor != VENDOR_ID:
                self.note(f"node {nid}: identity mismatch {dev:08X} {vendor:08X}")
                return
            _sdo(remote, 0x1016, 1).raw = (MASTER_ID << 16) | SLAVE_CONSUMER_MS
            with self.mon_lock:
                self.mon[nid].enabled = True  # arms at its first heartbeat
            _sdo(remote, 0x1017).raw = SLAVE_HB_MS
            self.mon[nid].booted += 1
            self.note(
                f"node {nid} configured: 1000h {dev:08X}, 1018h:01 {vendor:08X}, "
                f"1016h:01 = {(MASTER_ID << 16) | SLAVE_CONSUMER_MS:08X}, 1017h = {SLAVE_HB_MS}"
            )

    def reset_node(self, nid: int, why: str) -> None:
        with self.mon_lock:
            m = self.mon[nid]
            m.enabled = m.armed = False
            m.awaiting_since, m.alive_reported = time.perf_counter(), False
        self.note(f"node {nid}: {why} -> reset node")
        self.nmt(CS_RESET_NODE, nid)

    # -- main program -------------------------------------------------------
    def power_on(self) -> None:
        """Start the master's application thread (boot-up at once)."""
        for target in (self._run, self._watch):
            t = threading.Thread(target=target, name=f"master-{target.__name__}", daemon=True)
            t.start()
            self._threads.append(t)

    def _run(self) -> None:
        with self.lock:
            self.powered = True
            self.local.nmt.state = "INITIALISING"  # 701#00
            self.local.nmt.state = "PRE-OPERATIONAL"  # heartbeat 200 ms, 701#7F at once
            self.note("boot-up, PRE-OPERATIONAL, heartbeat producer 200 ms")
        if self._stop.wait(0.050):
            return
        self.nmt(CS_RESET_COMM, 0)  # 82 00
        pending = set(self.mon)
        while pending and not self._stop.is_set():
            try:
                kind, nid, _ = self.events.get(timeout=0.05)
            except queue.Empty:
                continue
            if kind == "bootup":
                self.note(f"node {nid}: boot-up")
                self.configure(nid)
                pending.discard(nid)
        if self._stop.is_set():
            return
        with self.lock:
            self.local.nmt.state = "OPERATIONAL"  # next heartbeat: 701#05
            self.operational = True
            self.note("all mandatory slaves configured: master OPERATIONAL")
            self.nmt(CS_START, 0)  # 01 00
        self.started.set()
        while not self._stop.is_set():
            try:
                kind, nid, _ = self.events.get(timeout=0.05)
            except queue.Empty:
                continue
            if kind == "bootup":
                self.note(f"node {nid}: boot-up")
                self.configure(nid)
                if self.operational:
                    self.nmt(CS_START, nid)
            elif kind == "timeout":
                self.reset_node(nid, f"heartbeat event ({self.consumer_s(nid) * 1000:.0f} ms)")
            elif kind == "alive":
                self.reset_node(nid, "heartbeat while waiting for boot-up (reset missed)")
            elif kind == "boot_timeout":
                self.reset_node(nid, "no boot-up within boot time")

    def stop(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join()
        self.local.nmt.stop_heartbeat()

    # -- scenario actions ---------------------------------------------------
    def wait_phase(self, nid: int, after: float) -> None:
        """Return `after` seconds after a heartbeat of nid (master's view)."""
        deadline = time.perf_counter() + 2.0
        while time.perf_counter() < deadline:
            last = self.mon[nid].last
            now = time.perf_counter()
            if last and 0 <= now - last - after < 0.003:
                return
            time.sleep(0.0005)
        raise RuntimeError(f"no heartbeat phase of node {nid}")


# --------------------------------------------------------------------------
# Scenarios
# --------------------------------------------------------------------------

SLAVE_POWER_ON = 0.300  # healthy etc.: slaves' boot-ups at +300/310/320 ms
MASTER_POWER_ON = 0.100


def _setup(b: MasterBench) -> Cia302Master:
    for nid in SLAVES:
        b.add_slave(nid)
    m = Cia302Master(b)
    b.start_pdo_scheduler()
    return m


def _start_normally(b: MasterBench, m: Cia302Master) -> None:
    """Master powers on at 0.100, slaves at 0.300/0.310/0.320 (still
    initialising when the master's 82 00 goes out)."""
    b.at(MASTER_POWER_ON)
    m.power_on()
    for i, nid in enumerate(SLAVES):
        b.at(SLAVE_POWER_ON + 0.010 * i)
        b.power_on(nid)
    if not m.started.wait(3.0):
        raise RuntimeError("master did not start the network")


def scenario_healthy(b: MasterBench) -> None:
    m = _setup(b)
    _start_normally(b, m)
    b.at(b.rel() + 5.2)


def scenario_late_master(b: MasterBench) -> None:
    m = _setup(b)
    for i, nid in enumerate(SLAVES):
        b.at(0.100 + 0.010 * i)
        b.power_on(nid)  # boot-up, then silent (1017h = 0)
    b.at(2.150)
    m.power_on()
    if not m.started.wait(3.0):
        raise RuntimeError("master did not start the network")
    b.at(b.rel() + 3.0)


def scenario_unplugged(b: MasterBench) -> None:
    m = _setup(b)
    _start_normally(b, m)
    b.at(2.0)
    m.wait_phase(3, 0.010)
    b.unplug(3)
    t = b.rel()
    b.at(t + 1.5)
    b.plug_in(3)
    b.at(t + 4.0)


def scenario_reboot(b: MasterBench) -> None:
    m = _setup(b)
    _start_normally(b, m)
    b.at(2.3)
    m.wait_phase(3, 0.010)
    b.spontaneous_reboot(3)
    b.at(b.rel() + 3.0)


def scenario_broadcast(b: MasterBench) -> None:
    m = _setup(b)
    _start_normally(b, m)
    b.at(2.2)
    m.wait_phase(2, 0.060)
    m.nmt(CS_PREOP, 0)  # 80 00: slaves to PRE-OPERATIONAL, master stays OPERATIONAL
    b.at(b.rel() + 0.3)
    with m.lock:
        for nid in SLAVES:  # e.g. check the identity again while pre-operational
            _ = _sdo(m.net[nid], 0x1018, 2).raw
        m.note("SDO upload 1018h:02 of nodes 2, 3, 4 while PRE-OPERATIONAL")
    b.at(b.rel() + 0.7)
    m.wait_phase(2, 0.060)
    m.nmt(CS_START, 0)  # 01 00
    b.at(b.rel() + 2.0)


def scenario_period_change(b: MasterBench) -> None:
    m = _setup(b)
    _start_normally(b, m)
    b.at(2.5)
    m.wait_phase(3, 0.060)
    with m.lock:
        m.set_consumer(3, int(PERIOD_CHANGE_MS * 1.5))  # own consumer first
        _sdo(m.net[3], 0x1017).raw = PERIOD_CHANGE_MS
        m.note(f"node 3: 1017h = {PERIOD_CHANGE_MS} ms confirmed")
    b.at(b.rel() + 4.5)


SCENARIOS: dict[str, Callable[[MasterBench], None]] = {
    "healthy": scenario_healthy,
    "late_master": scenario_late_master,
    "unplugged": scenario_unplugged,
    "reboot": scenario_reboot,
    "broadcast": scenario_broadcast,
    "period_change": scenario_period_change,
}


def write_log(frames: list[can.Message], path: Path) -> None:
    writer = can.CanutilsLogWriter(path, channel=LOG_CHANNEL)
    for msg in frames:
        writer.on_message_received(
            can.Message(
                timestamp=msg.timestamp,
                arbitration_id=msg.arbitration_id,
                is_extended_id=msg.is_extended_id,
                is_remote_frame=msg.is_remote_frame,
                dlc=msg.dlc,
                data=None if msg.is_remote_frame else msg.data,
                is_rx=True,
                channel=None,
            )
        )
    writer.stop()


# --------------------------------------------------------------------------
# Verification at frame level
# --------------------------------------------------------------------------


def _nmt(frames: list[can.Message], cs: int | None = None,
         nid: int | None = None) -> list[can.Message]:
    return [
        m
        for m in frames
        if m.arbitration_id == 0
        and (cs is None or m.data[0] == cs)
        and (nid is None or m.data[1] == nid)
    ]


def _ec(frames: list[can.Message], nid: int) -> list[can.Message]:
    return [m for m in frames if m.arbitration_id == 0x700 + nid and not m.is_remote_frame]


def _boot(frames: list[can.Message], nid: int) -> list[can.Message]:
    return [m for m in _ec(frames, nid) if m.data[0] == 0]


def _hb(frames: list[can.Message], nid: int) -> list[can.Message]:
    return [m for m in _ec(frames, nid) if m.data[0] != 0]


def _iv(ms: list[can.Message]) -> list[float]:
    return [b.timestamp - a.timestamp for a, b in pairwise(ms)]


def _sdo_req(frames: list[can.Message], nid: int, request: bytes) -> list[can.Message]:
    return [m for m in frames if m.arbitration_id == 0x600 + nid and bytes(m.data) == request]


def _resp_after(frames: list[can.Message], nid: int, req: can.Message) -> can.Message:
    return next(
        m for m in frames if m.arbitration_id == 0x580 + nid and m.timestamp >= req.timestamp
    )


W1017 = bytes([0x2B, 0x17, 0x10, 0x00, SLAVE_HB_MS, 0, 0, 0])
W1016 = bytes([0x23, 0x16, 0x10, 0x01]) + ((MASTER_ID << 16) | SLAVE_CONSUMER_MS).to_bytes(
    4, "little"
)


def check_common(frames: list[can.Message], rel: Callable[[can.Message], float]) -> list[str]:
    """What every recording must show: the master's start-up, one boot-slave
    sequence per boot-up, heartbeats only after 1017h, PDO gating, no abort."""
    ev: list[str] = []
    ids = {m.arbitration_id for m in frames}
    assert ids <= {0, 0x701} | {c + n for n in SLAVES for c in (0x180, 0x580, 0x600, 0x700)}, (
        sorted(hex(i) for i in ids)
    )
    assert not any(m.is_remote_frame or m.is_extended_id for m in frames)
    assert not any(m.dlc != 2 for m in _nmt(frames)), "NMT DLC"
    assert not any(0x580 < m.arbitration_id < 0x600 and m.data[0] == 0x80 for m in frames), (
        "SDO abort"
    )
    # master
    mec = _ec(frames, MASTER_ID)
    assert mec[0].data[0] == 0 and mec[1].data[0] == 0x7F, "master boot-up, 7Fh"
    assert mec[1].timestamp - mec[0].timestamp < 0.005
    assert len(_boot(frames, MASTER_ID)) == 1, "master boots once"
    rc = _nmt(frames, CS_RESET_COMM, 0)
    assert len(rc) == 1 and 0.045 < rc[0].timestamp - mec[0].timestamp < 0.060
    start_all = _nmt(frames, CS_START, 0)[0]
    mhb = _hb(frames, MASTER_ID)
    iv = _iv(mhb)
    assert all(0.185 < x < 0.215 for x in iv), f"master heartbeat intervals {iv}"
    first05 = next(m for m in mhb if m.data[0] == 5)
    assert all(m.data[0] == 0x7F for m in mhb if m.timestamp < first05.timestamp)
    assert all(m.data[0] == 5 for m in mhb if m.timestamp >= first05.timestamp)
    assert 0 <= first05.timestamp - start_all.timestamp < 0.205
    ev.append(
        f"master: boot-up 701#00 @{rel(mec[0]):.3f}, 701#7F "
        f"+{(mec[1].timestamp - mec[0].timestamp) * 1000:.2f} ms, "
        f"82 00 @{rel(rc[0]):.3f}, 01 00 @{rel(start_all):.3f}, first 701#05 @{rel(first05):.3f}; "
        f"{len(mhb)} heartbeats {min(iv) * 1000:.1f}..{max(iv) * 1000:.1f} ms apart, "
        f"all 05h from then on"
    )
    # slaves
    for nid in SLAVES:
        boots = _boot(frames, nid)
        ec = _ec(frames, nid)
        for i, bt in enumerate(boots):
            nxt = boots[i + 1].timestamp if i + 1 < len(boots) else float("inf")
            # boot slave: 1000h, 1018h:01, 1016h:01, 1017h, in this order, no heartbeat before 1017h
            reqs = [
                m
                for m in frames
                if m.arbitration_id == 0x600 + nid and bt.timestamp < m.timestamp < nxt
            ]
            if bt.timestamp < mec[0].timestamp:  # before the master is up: silent, unconfigured
                assert not reqs and not [
                    m
                    for m in frames
                    if (m.arbitration_id & 0x7F) == nid and bt.timestamp < m.timestamp < nxt
                ], f"node {nid}: frames after its power-on boot-up before the master"
                continue
            heads = [bytes(m.data[:4]) for m in reqs[:4]]
            assert heads == [
                bytes.fromhex("40001000"),
                bytes.fromhex("40181001"),
                W1016[:4],
                W1017[:4],
            ], (nid, [h.hex() for h in heads])
            assert bytes(reqs[2].data) == W1016 and bytes(reqs[3].data) == W1017
            conf = _resp_after(frames, nid, reqs[3])
            assert bytes(conf.data) == bytes.fromhex("6017100000000000")
            hbs = [m for m in ec if bt.timestamp < m.timestamp < nxt]
            assert hbs and reqs[3].timestamp <= hbs[0].timestamp <= conf.timestamp, (
                "first heartbeat between the 1017h request and its confirmation"
            )
        # PDO gating: TPDO only between a start (01 00 / 01 N) and the next
        # state-leaving event (pre-op/stop/reset command, boot-up)
        events = sorted(
            [(m.timestamp, 0, m) for m in _nmt(frames) if m.data[1] in (0, nid)]
            + [(m.timestamp, 0, m) for m in boots]
            + [(m.timestamp, 1, m) for m in frames if m.arbitration_id == 0x180 + nid],
            key=lambda e: (e[0], e[1]),
        )
        state, bad = "PRE", []
        for ts, kind, m in events:
            if kind == 0:
                state = "OP" if m.arbitration_id == 0 and m.data[0] == CS_START else "OTHER"
            elif state != "OP":
                bad.append(f"{ts:.3f}")
        assert not bad, f"node {nid}: TPDO outside OPERATIONAL at {bad}"
    return ev


def _slave_hb_line(frames: list[can.Message], nid: int, rel: Callable[[can.Message], float],
                   since: float | None = None, until: float | None = None) -> str:
    hb = [
        m
        for m in _hb(frames, nid)
        if (since is None or m.timestamp >= since) and (until is None or m.timestamp < until)
    ]
    iv = _iv(hb)
    states = "/".join(f"{s:02X}" for s in sorted({m.data[0] for m in hb}))
    return (
        f"node {nid}: {len(hb)} heartbeats {states} {rel(hb[0]):.3f}..{rel(hb[-1]):.3f}, "
        f"intervals {min(iv) * 1000:.1f}..{max(iv) * 1000:.1f} ms (median "
        f"{statistics.median(iv) * 1000:.1f})"
    )


def verify(name: str, frames: list[can.Message]) -> list[str]:
    t0 = frames[0].timestamp

    def rel(m: can.Message | float) -> float:
        out: float = (m.timestamp if hasattr(m, "timestamp") else m) - t0
        return out

    ev = check_common(frames, rel)
    mboot = _boot(frames, MASTER_ID)[0]
    start_all = _nmt(frames, CS_START, 0)[0]
    boots = {nid: _boot(frames, nid) for nid in SLAVES}
    ev.append(
        "boot-ups: "
        + "; ".join(
            f"node {nid} " + ", ".join(f"{rel(m):.3f}" for m in bs) for nid, bs in boots.items()
        )
    )
    direct = [m for m in _nmt(frames) if m.data[1] != 0]

    def steady(nid: int, since: float, until: float | None = None, lo: float = 0.090,
               hi: float = 0.110) -> None:
        hb = [
            m
            for m in _hb(frames, nid)
            if m.timestamp >= since and (until is None or m.timestamp < until)
        ]
        iv = _iv(hb)
        assert iv and all(lo < x < hi for x in iv), (nid, [round(x, 4) for x in iv])

    if name in ("healthy", "late_master", "broadcast", "period_change"):
        assert not direct, f"direct NMT commands {[m.data.hex() for m in direct]}"
        for nid in SLAVES:
            assert len(boots[nid]) == (2 if name == "late_master" else 1), (nid, boots[nid])
            if name != "period_change" or nid != 3:
                steady(nid, boots[nid][-1].timestamp)
            ev.append(_slave_hb_line(frames, nid, rel))
        first_slave = min(b[0].timestamp for b in boots.values())
        rc = _nmt(frames, CS_RESET_COMM, 0)[0]
        if name == "late_master":
            assert mboot.timestamp - first_slave > 1.9, "master ~2 s after the slaves"
            for nid in SLAVES:  # silent between power-on boot-up and the reset
                assert not [
                    m
                    for m in frames
                    if (m.arbitration_id & 0x7F) == nid
                    and boots[nid][0].timestamp < m.timestamp < rc.timestamp
                ]
            ev.append(
                f"slaves power-on boot-ups {rel(first_slave):.3f}..; silent until 82 00 "
                f"@{rel(rc):.3f} (master boot-up {rel(mboot):.3f}); boot-ups after the reset "
                + ", ".join(
                    f"{(boots[n][1].timestamp - rc.timestamp) * 1000:.0f} ms" for n in SLAVES
                )
            )
        else:
            assert first_slave > rc.timestamp, "slaves boot after the master's 82 00"
        t_end = frames[-1].timestamp
        ev.append(
            f"01 00 @{rel(start_all):.3f}; trace ends {rel(t_end):.3f} "
            f"({t_end - start_all.timestamp:.2f} s of operation)"
        )
    if name == "broadcast":
        pre = _nmt(frames, CS_PREOP, 0)
        starts = _nmt(frames, CS_START, 0)
        assert len(pre) == 1 and len(starts) == 2, (len(pre), len(starts))
        p, s2 = pre[0], starts[1]
        mhb = [m for m in _hb(frames, MASTER_ID) if p.timestamp < m.timestamp < s2.timestamp]
        assert mhb and all(m.data[0] == 5 for m in mhb)
        for nid in SLAVES:
            between = [m for m in _hb(frames, nid) if p.timestamp < m.timestamp < s2.timestamp]
            assert between and all(m.data[0] == 0x7F for m in between), nid
            assert not [
                m
                for m in frames
                if m.arbitration_id == 0x180 + nid and p.timestamp < m.timestamp < s2.timestamp
            ]
            next_hb = next(m for m in _hb(frames, nid) if m.timestamp > s2.timestamp)
            assert next_hb.data[0] == 5
        uploads = [
            m
            for m in frames
            if 0x600 < m.arbitration_id < 0x680 and p.timestamp < m.timestamp < s2.timestamp
        ]
        ev.append(
            f"80 00 @{rel(p):.3f}: slaves 7Fh from their next heartbeat, no TPDO; master keeps "
            f"701#05 ({len(mhb)} heartbeats {rel(mhb[0]):.3f}..{rel(mhb[-1]):.3f}); "
            f"{len(uploads)} SDO uploads (1018h:02) while pre-op; 01 00 @{rel(s2):.3f}"
        )
    if name == "period_change":
        reqs = _sdo_req(
            frames,
            3,
            bytes([0x2B, 0x17, 0x10, 0x00]) + PERIOD_CHANGE_MS.to_bytes(2, "little") + bytes(2),
        )
        assert len(reqs) == 1
        req = reqs[0]
        conf = _resp_after(frames, 3, req)
        assert bytes(conf.data) == bytes.fromhex("6017100000000000")
        hb3 = _hb(frames, 3)
        before = [m for m in hb3 if m.timestamp < req.timestamp]
        after = [m for m in hb3 if m.timestamp >= req.timestamp]
        steady(3, boots[3][0].timestamp, req.timestamp)
        steady(3, req.timestamp, None, 0.290, 0.310)
        gap_before = after[0].timestamp - before[-1].timestamp
        assert 0.050 < gap_before < 0.100, gap_before
        assert req.timestamp <= after[0].timestamp <= conf.timestamp
        ev.append(
            f"node 3: 1017h = {PERIOD_CHANGE_MS} request 603#{req.data.hex()} @{rel(req):.4f}, "
            f"confirmed 583#{conf.data.hex()} @{rel(conf):.4f}; first heartbeat at the new period "
            f"@{rel(after[0]):.4f} (before the confirmation; {gap_before * 1000:.1f} ms after the "
            f"previous heartbeat); "
            + _slave_hb_line(frames, 3, rel, until=req.timestamp).split(": ", 1)[1]
            + " before, "
            + _slave_hb_line(frames, 3, rel, since=req.timestamp).split(": ", 1)[1]
            + " after"
        )
    if name == "unplugged":
        hb3 = _hb(frames, 3)
        gaps = [(a, b) for a, b in pairwise(hb3) if b.timestamp - a.timestamp > 0.150]
        assert len(gaps) == 1, [(rel(a), rel(b)) for a, b in gaps]
        last, back = gaps[0]
        silent = [
            m
            for m in frames
            if (m.arbitration_id & 0x7F) == 3
            and m.arbitration_id != 0x603
            and last.timestamp < m.timestamp < back.timestamp
        ]
        assert not silent
        resets = _nmt(frames, CS_RESET_NODE, 3)
        assert len(resets) == 2, [rel(m) for m in resets]
        r1, r2 = resets
        assert 0.240 < r1.timestamp - last.timestamp < 0.270, r1.timestamp - last.timestamp
        assert r1.timestamp < back.timestamp < r2.timestamp
        assert back.data[0] == 5
        assert 1.40 < back.timestamp - last.timestamp < 1.60
        between = [m for m in _ec(frames, 3) if r1.timestamp < m.timestamp < r2.timestamp]
        assert between == [back], [(rel(m), m.data.hex()) for m in between]
        assert len(boots[3]) == 2 and r2.timestamp < boots[3][1].timestamp
        s3 = _nmt(frames, CS_START, 3)
        assert len(s3) == 1 and s3[0].timestamp > boots[3][1].timestamp
        steady(3, boots[3][0].timestamp, last.timestamp + 0.001)
        steady(3, boots[3][1].timestamp)
        pdo_gap = [m for m in frames if m.arbitration_id == 0x183]
        ev.append(
            f"node 3: last heartbeat {last.data[0]:02X}h @{rel(last):.3f}; silent (no heartbeat, "
            f"no TPDO) until {rel(back):.3f} ({(back.timestamp - last.timestamp) * 1000:.0f} ms); "
            f"master's 81 03 @{rel(r1):.3f} "
            f"(+{(r1.timestamp - last.timestamp) * 1000:.0f} ms after the last heartbeat; "
            f"missed); node 3 back with heartbeat {back.data[0]:02X}h @{rel(back):.3f}, "
            f"no boot-up; master's second 81 03 @{rel(r2):.3f} "
            f"(+{(r2.timestamp - back.timestamp) * 1000:.2f} ms); "
            f"boot-up @{rel(boots[3][1]):.3f}; reconfigured, 01 03 @{rel(s3[0]):.3f}; "
            f"183h frames {len(pdo_gap)}"
        )
        for nid in (2, 4):
            assert len(boots[nid]) == 1
            steady(nid, boots[nid][0].timestamp)
    if name == "reboot":
        assert len(boots[3]) == 2
        rb = boots[3][1]
        assert not [
            m
            for m in _nmt(frames)
            if m.data[0] in (CS_RESET_NODE, CS_RESET_COMM) and m.timestamp > start_all.timestamp
        ]
        last = [m for m in _hb(frames, 3) if m.timestamp < rb.timestamp][-1]
        assert 0.030 < rb.timestamp - last.timestamp < 0.080, rb.timestamp - last.timestamp
        s3 = _nmt(frames, CS_START, 3)
        assert len(s3) == 1 and s3[0].timestamp > rb.timestamp
        after = [m for m in _hb(frames, 3) if m.timestamp > rb.timestamp]
        pdo_off = [
            m
            for m in frames
            if m.arbitration_id == 0x183 and last.timestamp < m.timestamp < s3[0].timestamp
        ]
        steady(3, boots[3][0].timestamp, last.timestamp + 0.001)
        steady(3, rb.timestamp)
        ev.append(
            f"node 3: last heartbeat {last.data[0]:02X}h @{rel(last):.3f}; boot-up (no command) "
            f"@{rel(rb):.3f} ({(rb.timestamp - last.timestamp) * 1000:.0f} ms later); reconfigured "
            f"(first heartbeat {after[0].data[0]:02X}h @{rel(after[0]):.3f}), "
            f"01 03 @{rel(s3[0]):.3f}; "
            f"TPDO between {len(pdo_off)}"
        )
        for nid in (2, 4):
            assert len(boots[nid]) == 1
            steady(nid, boots[nid][0].timestamp)
    return ev


def check_file(name: str, outdir: Path, say: Callable[[str], None],
               recorded: int | None = None) -> int:
    path = outdir / f"{name}.log"
    frames = read_back(path)
    say(f"   {path.name}: {len(frames)} frames, {path.stat().st_size} bytes")
    failures = 0
    if recorded is not None and len(frames) != recorded:
        say(f"   FAIL: recorded {recorded}, read back {len(frames)}")
        failures += 1
    keys = [(m.timestamp, m.arbitration_id, bytes(m.data)) for m in frames]
    if len(set(keys)) != len(keys):
        say("   FAIL: duplicate frames")
        failures += 1
    say(summarize(frames))
    try:
        for line in verify(name, frames):
            say(f"   evidence: {line}")
        say("   OK: intended behaviour present")
    except (AssertionError, StopIteration, IndexError) as exc:
        say(f"   FAIL: {exc!r}")
        failures += 1
    return failures


def run(names: list[str], outdir: Path, quiet: bool, check_only: bool) -> int:
    say = (lambda s: None) if quiet else print
    outdir.mkdir(parents=True, exist_ok=True)
    failures = 0
    for name in names:
        if check_only:
            say(f"== {name}")
            failures += check_file(name, outdir, say)
            continue
        bench = MasterBench(name)
        t = time.perf_counter()
        try:
            SCENARIOS[name](bench)
        finally:
            frames = bench.finish()
        write_log(frames, outdir / f"{name}.log")
        say(f"== {name}: {len(frames)} frames recorded in {time.perf_counter() - t:.1f} s")
        for note in bench.notes:
            say(f"   {note}")
        failures += check_file(name, outdir, say, recorded=len(frames))
    say(f"{failures} failure(s)")
    return 1 if failures else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--outdir",
        type=Path,
        default=Path(__file__).resolve().parent / "canopen_master",
        help="where to write <name>.log (default: samples/canopen_master)",
    )
    parser.add_argument("--only", nargs="+", choices=list(SCENARIOS), metavar="NAME")
    parser.add_argument("--check-only", action="store_true", help="verify the existing logs")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    return run(args.only or list(SCENARIOS), args.outdir, args.quiet, args.check_only)


if __name__ == "__main__":
    sys.exit(main())
