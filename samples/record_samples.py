#!/usr/bin/env python3
"""Record sample CANopen NMT traces for nmtcheck from a real CANopen stack.

Every frame in the sample logs comes from the python ``canopen`` library
(2.4.1), running on python-can's in-process ``virtual`` interface. Nothing is
made up by hand. For each scenario:

* one ``canopen.Network`` is the NMT master (``RemoteNode`` objects for the
  slaves, NMT commands, SDO client, node guarding);
* every slave is a ``canopen.LocalNode`` on its own ``canopen.Network``,
  connected to the same virtual channel. Its object dictionary is built in
  code (:func:`build_od`: 1000h, 1017h, 1018h, 100Ch/100Dh, TPDO1
  1800h/1A00h mapping 6000h/6001h);
* a separate python-can virtual bus with a ``can.Notifier`` records the
  channel. Virtual buses deliver a frame to every *other* bus on the channel.
  No bus uses ``receive_own_messages``, so the recorder sees each frame once.
  The script checks this: it counts the frames every bus sent and compares
  the count with the recording, and it checks for duplicates.

Each recording is written with python-can's own writers,
``can.CanutilsLogWriter`` (``<name>.log``, candump ``-L`` format, interface
``can0``) and ``can.ASCWriter`` (``<name>.asc``, channel 1). Then both files
are read back with ``can.LogReader``. The script prints a per-CAN-ID summary
and checks that the intended fault really is in the frames. If a check
fails, the exit status is 1.

A full run (no ``--only``) also exports one DCF per slave of ``healthy``
(``devices/node2.dcf`` ... ``node4.dcf``) with canopen's own exporter,
``canopen.export_od(od, path, doc_type="dcf")``, from the object dictionary
:func:`build_od` gives that slave, and writes ``network.toml`` (SPEC section
6) naming them. Each DCF is imported back with ``canopen.import_od`` and
must hold the same objects and values, with 1017h = 100.

Usage::

    python samples/record_samples.py [--outdir DIR] [--only NAME ...] [--quiet]
    python samples/record_samples.py --check-only   # verify existing files only
    python samples/record_samples.py --dcf-only     # only devices/*.dcf, network.toml

Timing and determinism
----------------------
Each scenario runs on a fixed schedule, measured from its start (t0).

* Slaves boot at t0+100 ms, +110 ms, +120 ms. That sets their heartbeat
  phases (python-can's cyclic tasks use absolute due times, so they do not
  drift).
* The script's TPDO scheduler ticks at 35 ms and 85 ms modulo 100 ms.
* The master acts at about 60 ms modulo 100 ms.
* In ``sdo_config`` and ``ignored_1017`` the master writes 1017h at t0+200
  ms and t0+210 ms. canopen starts the heartbeat at the write, so the
  phases are the same 0 ms and 10 ms modulo 100 ms.

Periodic frames and commands are therefore always tens of milliseconds
apart. Every run gives the same frames in the same order; only the
timestamps jitter by fractions of a millisecond. The recorded frames are
sorted by their send timestamp (stable sort) before writing. On a heavily
loaded machine a periodic stream can still gain or lose a frame at a
scenario boundary.

NMT-state gating of PDOs
------------------------
canopen's ``LocalNode`` does *not* gate its TPDOs on the NMT state
(``PdoMap.transmit()`` and ``PdoMap.start()`` send in any state). So the
well-behaved slaves here use a small application-level scheduler. Under one
lock, it transmits TPDO1 only while ``node.nmt.state == 'OPERATIONAL'``. The
master's NMT helper holds the same lock from sending the command until every
addressed slave has processed it. A real device does the same when it
handles the NMT frame atomically with its PDO task. As a result, no TPDO of a
well-behaved node is ever stamped later than a command that takes it out of
OPERATIONAL, not even within a grace window.

What canopen 2.4.1 does (seen in these recordings)
--------------------------------------------------
* A ``LocalNode`` sends **no boot-up by itself**: connecting sends nothing.
  Setting ``nmt.state = 'PRE-OPERATIONAL'`` straight away starts heartbeats
  (7Fh) with no boot-up at all. The boot-up (700h+N, 00h) is sent only when
  the application sets ``nmt.state = 'INITIALISING'``
  (``NmtSlave.send_command``). The script does that, then sets
  'PRE-OPERATIONAL'. This starts the heartbeat task, and python-can's cyclic
  task sends the first 7Fh heartbeat *immediately*, less than 1 ms after the
  boot-up.
* A received NMT command only updates the data of the running heartbeat
  task, so the new state shows in the *next periodic* heartbeat (about
  40-60 ms after the command here). No extra heartbeat is sent on a state
  change.
* A received reset node (81h) or reset communication (82h) sets the state
  to 0 (INITIALISING) and leaves it there. The heartbeat task keeps running
  and now sends **00h every heartbeat period, forever**. No boot-up follows
  and the node never returns to PRE-OPERATIONAL. The master's
  ``NmtMaster.wait_for_bootup()`` accepts the first of these 00h heartbeats
  as "the boot-up".
* ``NmtMaster.start_node_guarding(period)`` sends **DLC-0 remote frames** on
  700h+N (``send_periodic(..., None, period, remote=True)``). ``LocalNode``
  does not answer RTRs (canopen's ``MessageListener`` drops remote frames),
  so the script answers them with a python-can ``Listener`` on the slave's
  own bus.
* python-can 4.6.1's ``CanutilsLogWriter`` appends the direction flag
  (`` R``: every frame is received from the recorder's point of view) and
  writes a remote frame as ``705#R`` with no DLC digit.
* An SDO write of 1017h to a ``LocalNode`` **does** change its heartbeat:
  ``LocalNode.__init__`` registers ``NmtSlave.on_write`` as a write
  callback, and it calls ``start_heartbeat(value)`` (``stop_heartbeat()``
  for 0) in any NMT state. The SDO server runs the write callbacks before
  it sends its 60h confirmation, and python-can's cyclic task sends the
  first heartbeat at once, so the first 7Fh heartbeat is on the bus about
  0.1-0.3 ms *before* the confirmation. The new period's phase is the
  moment of the write. ``LocalNode`` has no heartbeat consumer: a written
  1016h entry is only stored.
* canopen's ``export_od(..., doc_type="dcf")`` writes the object
  dictionary's defaults as ``DefaultValue`` (no ``ParameterValue``, since
  the script sets no values) and the node-ID as ``[DeviceComissioning]
  NodeID``. Its ``[FileInfo]`` dates are the export time (and the
  "time" fields use the month for minutes: ``%I:%m%p``).

Scenarios (file stems) and the nmtcheck findings expected (SPEC section 3)
--------------------------------------------------------------------------
``healthy``
    Nodes 2, 3, 4 with a 100 ms heartbeat (1017h).
    Sequence: boot-ups; SDO upload of 1018h:01 from node 2 while
    PRE-OPERATIONAL; NMT start all (01 00); heartbeats 05h; TPDO1 (180h+N)
    every 50 ms while OPERATIONAL; enter pre-operational node 3 (80 03), so
    node 3's PDOs stop and it sends 7Fh; start node 3 (01 03); SDO upload of
    1017h from node 2 while OPERATIONAL; stop all (02 00), heartbeats 04h,
    no PDO or SDO after that.
    Expected: **no findings** (clean under CiA 301).
``heartbeat_loss``
    Nodes 2 and 3, started and sending PDOs. In the middle, node 3 drops off
    the bus for about 1.1 s, as if its controller went bus-off and
    recovered: its heartbeat and its PDOs stop, and about 10 heartbeat
    periods are missing. Then it comes back in OPERATIONAL with no boot-up.
    Expected: **H001** (heartbeat-timeout) for node 3, once. Node 3 is
    OFFLINE from the timeout until it comes back.
``pdo_preop``
    Node 2's application starts its TPDO1 with canopen's own
    ``tpdo[1].start(0.05)`` right after boot-up. canopen sends it in
    PRE-OPERATIONAL, before any start command, for about 0.9 s. Node 3
    waits for OPERATIONAL. Then NMT start all.
    Expected: **S001** (pdo-while-not-operational) for node 2, once (one
    finding for the run of PDOs). Nothing for node 3.
``guard_toggle``
    Node guarding instead of heartbeat: nodes 5 and 6 have 1017h = 0, so
    after the boot-up they send no heartbeats. The master guards both every
    100 ms (``start_node_guarding(0.1)``, DLC-0 RTR on 705h/706h). The
    script's responder answers each RTR with a DLC-1 data frame: state
    plus toggle bit 7. Toggle sequences:

    * node 6: 0, 1, 0, 1, ... (correct; the first response after boot-up
      has t=0);
    * node 5: 0, 1, 0, 1, then **1 again** (the 5th response repeats the
      toggle), then alternating again.

    Master sends start all after about 0.5 s of guarding, so the responses
    change from FFh/7Fh to 85h/05h.
    Expected: **G001** (guard-toggle) for node 5, once. Nothing for node 6.
``ignored_command``
    Nodes 2 and 4 with a 100 ms heartbeat. Start node 2 (01 02): node 2
    obeys (05h). Start node 4 (01 04): node 4's firmware drops the command,
    and it keeps sending 7Fh for about 2 s.
    Expected: **S004** (command-not-obeyed) for node 4, once. Nothing for
    node 2.
``reset_no_bootup``
    Nodes 2 and 3, started and sending PDOs. The master resets node 3
    (81 03) and waits with canopen's ``wait_for_bootup()``. canopen's
    LocalNode then heartbeats 00h every 100 ms, with no boot-up and no
    return to PRE-OPERATIONAL, for the 2 s left in the recording. The
    master's ``wait_for_bootup()`` returns at the first 00h heartbeat.
    Expected: **B003** (bootup-repeated) for node 3, once (one finding per
    run).
    B001 (missing-bootup) is *not* expected under SPEC section 2's reading.
    The first 00h frame after the reset is a boot-up by definition (a data
    frame on 700h+N with 00h), and no other frame of node 3 comes between
    the reset and that 00h.
``sdo_config``
    Nodes 2 and 3 boot with 1017h = 0 in their object dictionaries, so
    after the boot-up they send no heartbeat. The master configures them at
    boot with expedited SDO downloads through canopen's SDO client
    (``node.sdo[0x1017].raw = 100``): ``602#2B17100064000000``, answered
    ``582#6017100000000000`` by the LocalNode's SDO server, 100 ms after
    node 2's boot-up; the same to node 3 at +10 ms. canopen's LocalNode
    starts heart-beating at once, every 100 ms (7Fh, then 05h). Then
    node 2's consumer entry 1016h:01 = 000300FAh (node 3, 250 ms):
    ``602#23161001FA000300`` / ``582#6016100100000000``. Then NMT start
    all; TPDO1 every 50 ms while OPERATIONAL.
    Expected: **no findings**.
``ignored_1017``
    Like ``sdo_config``, but node 3's firmware has a fixed 500 ms heartbeat
    (1017h = 500 in its dictionary, heart-beating from the boot-up). It
    accepts the master's 1017h = 100 download (confirms with 60h, and an
    SDO upload of 1017h then answers 100), but its stack ignores the value
    (the script removes canopen's ``NmtSlave.on_write`` callback) and it
    keeps heart-beating every 500 ms, for 4.4 s after the write. Node 2's
    consumer entry names node 3 with 1000 ms (000303E8h), longer than node
    3's real period, so no consumer times out: with 250 ms, or with no
    entry (1.5 x the written 100 ms), every 500 ms gap would also be an
    H001.
    Expected: **H003** (heartbeat-period-mismatch) for node 3, once (median
    0.5 s vs 0.1 s written by SDO). Nothing for node 2.
"""

from __future__ import annotations

import argparse
import collections
import logging
import os
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
from canopen.nmt import NMT_STATES
from canopen.sdo.base import SdoArray, SdoRecord, SdoVariable

if sys.version_info >= (3, 11):
    import tomllib
else:  # Python 3.10
    import tomli as tomllib

LOG_CHANNEL = "can0"  # interface name written into the candump logs
HEARTBEAT_MS = 100  # 1017h of heartbeat producers
PDO_PERIOD = 0.050  # TPDO1 period (s), also 1800h:05 event timer
PDO_PHASE = 0.035  # scheduler ticks at t0 + 35 ms + k * 50 ms
BOOT_AT = 0.100  # first boot-up at t0 + 100 ms, then +10 ms each
VENDOR_ID = 0x4E4D5443  # made-up vendor-ID ("NMTC") for 1018h:01

STATE_CODE = {name: code for code, name in NMT_STATES.items()}

# NMT command specifiers (NMT_REFERENCE.md section 2)
CS_START, CS_STOP, CS_PREOP, CS_RESET_NODE, CS_RESET_COMM = 0x01, 0x02, 0x80, 0x81, 0x82


# --------------------------------------------------------------------------
# Object dictionary
# --------------------------------------------------------------------------


def _var(
    name: str,
    index: int,
    subindex: int,
    data_type: int,
    default: int,
    access: str = "ro",
    mappable: bool = False,
) -> od_mod.ODVariable:
    var = od_mod.ODVariable(name, index, subindex)
    var.data_type = data_type
    var.default = default
    var.access_type = access
    var.pdo_mappable = mappable
    return var


def build_od(node_id: int, heartbeat_ms: int, consumer_entries: int = 0) -> od_mod.ObjectDictionary:
    """A minimal CiA 301 object dictionary for one slave.

    1000h device type, 100Ch/100Dh guard time / life time factor, 1017h
    producer heartbeat time, 1018h identity, TPDO1 (1800h communication,
    1A00h mapping of 6000h counter + 6001h analogue value). With
    ``consumer_entries=n`` it also has 1016h (consumer heartbeat time, an
    ARRAY with n UNSIGNED32 entries, all 0 = unused) so that a master can
    write consumer entries over SDO. Without it there is no 1016h at all.
    """
    od = od_mod.ObjectDictionary()
    od.node_id = node_id
    od.add_object(_var("Device type", 0x1000, 0, od_mod.UNSIGNED32, 0x00000191))
    od.add_object(_var("Guard time", 0x100C, 0, od_mod.UNSIGNED16, 100, "rw"))
    od.add_object(_var("Life time factor", 0x100D, 0, od_mod.UNSIGNED8, 3, "rw"))
    if consumer_entries:
        consumer = od_mod.ODArray("Consumer heartbeat time", 0x1016)
        consumer.add_member(
            _var("Highest sub-index supported", 0x1016, 0, od_mod.UNSIGNED8, consumer_entries)
        )
        for sub in range(1, consumer_entries + 1):
            consumer.add_member(
                _var(f"Consumer heartbeat time {sub}", 0x1016, sub, od_mod.UNSIGNED32, 0, "rw")
            )
        od.add_object(consumer)
    od.add_object(_var("Producer heartbeat time", 0x1017, 0, od_mod.UNSIGNED16, heartbeat_ms, "rw"))

    ident = od_mod.ODRecord("Identity object", 0x1018)
    for sub, name, value in (
        (0, "Highest sub-index supported", 4),
        (1, "Vendor-ID", VENDOR_ID),
        (2, "Product code", 0x00000401),
        (3, "Revision number", 0x00010000),
        (4, "Serial number", 0x1000 + node_id),
    ):
        ident.add_member(
            _var(name, 0x1018, sub, od_mod.UNSIGNED8 if sub == 0 else od_mod.UNSIGNED32, value)
        )
    od.add_object(ident)

    comm = od_mod.ODRecord("TPDO1 communication parameter", 0x1800)
    for sub, name, dtype, value in (
        (0, "Highest sub-index supported", od_mod.UNSIGNED8, 5),
        (1, "COB-ID", od_mod.UNSIGNED32, 0x180 + node_id),
        (2, "Transmission type", od_mod.UNSIGNED8, 0xFE),
        (3, "Inhibit time", od_mod.UNSIGNED16, 0),
        (5, "Event timer", od_mod.UNSIGNED16, int(PDO_PERIOD * 1000)),
    ):
        comm.add_member(_var(name, 0x1800, sub, dtype, value, "rw"))
    od.add_object(comm)

    mapping = od_mod.ODRecord("TPDO1 mapping parameter", 0x1A00)
    for sub, dtype, value in (
        (0, od_mod.UNSIGNED8, 2),
        (1, od_mod.UNSIGNED32, 0x60000010),
        (2, od_mod.UNSIGNED32, 0x60010010),
    ):
        mapping.add_member(
            _var(
                "Number of mapped objects" if sub == 0 else f"Mapped object {sub}",
                0x1A00,
                sub,
                dtype,
                value,
                "rw",
            )
        )
    od.add_object(mapping)

    od.add_object(_var("Counter", 0x6000, 0, od_mod.UNSIGNED16, 0, "rw", True))
    od.add_object(_var("Analogue input", 0x6001, 0, od_mod.UNSIGNED16, 0, "rw", True))
    return od


# --------------------------------------------------------------------------
# Test bench: master, slaves, recorder
# --------------------------------------------------------------------------


class _Collector(can.Listener):
    """Collects every frame the recorder bus receives."""

    def __init__(self) -> None:
        self.frames: list[can.Message] = []
        self._lock = threading.Lock()

    def on_message_received(self, msg: can.Message) -> None:
        with self._lock:
            self.frames.append(msg)


class _GuardResponder(can.Listener):
    """Answers node-guarding RTRs on 700h+N for a LocalNode (canopen does not).

    The response is a DLC-1 data frame: bit 7 toggle, bits 0..6 NMT state.
    The toggle starts at 0 after boot-up and alternates. With
    ``repeat_toggle_at=k``, the toggle is not flipped after the (k-1)-th
    response, so the k-th response repeats the previous toggle (a G001
    fault).
    """

    def __init__(self, slave: Slave, repeat_toggle_at: int | None = None) -> None:
        self.slave = slave
        self.repeat_toggle_at = repeat_toggle_at
        self.toggle = 0
        self.responses = 0

    def on_message_received(self, msg: can.Message) -> None:
        if not (
            msg.is_remote_frame
            and not msg.is_extended_id
            and msg.arbitration_id == 0x700 + self.slave.node_id
        ):
            return
        if self.slave.silent:
            return
        state = STATE_CODE[self.slave.node.nmt.state]
        self.slave.network.send_message(
            0x700 + self.slave.node_id, bytes([(self.toggle << 7) | (state & 0x7F)])
        )
        self.responses += 1
        if self.repeat_toggle_at is None or self.responses + 1 != self.repeat_toggle_at:
            self.toggle ^= 1


@dataclass
class Slave:
    node_id: int
    node: canopen.LocalNode
    network: canopen.Network
    gated_pdo: bool = True  # TPDO1 from the NMT-gated scheduler
    silent: bool = False  # off the bus (no heartbeat, PDO, guarding)
    ignore_cs: frozenset[int] = frozenset()
    processed: int = 0  # NMT frames processed (for the master helper)
    cond: threading.Condition = field(default_factory=threading.Condition)
    counter: int = 0
    responder: _GuardResponder | None = None
    writes: list[str] = field(default_factory=list)  # SDO writes the server accepted


class Bench:
    """One scenario: virtual channel, recorder, NMT master and slaves."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.vchannel = f"nmtcheck-samples-{name}-{os.getpid()}"
        self.sent: dict[str, int] = collections.Counter()
        self.collector = _Collector()
        self.rec_bus = can.Bus(
            interface="virtual", channel=self.vchannel, receive_own_messages=False
        )
        self.rec_notifier = can.Notifier(self.rec_bus, [self.collector], timeout=0.1)

        self.master = canopen.Network()
        self.master.NOTIFIER_CYCLE = 0.1
        self.master.connect(interface="virtual", channel=self.vchannel, receive_own_messages=False)
        self._count_sends(self.master.bus, "master")

        self.slaves: dict[int, Slave] = {}
        self.pdo_lock = threading.Lock()
        self._stop = threading.Event()
        self._pdo_thread: threading.Thread | None = None
        self.t0 = time.perf_counter()
        self.notes: list[str] = []

    # -- plumbing ----------------------------------------------------------
    def _count_sends(self, bus: can.BusABC | None, who: str) -> None:
        """Count every frame a bus sends (canopen and python-can cyclic tasks
        both call ``bus.send``), to prove the recording holds each once."""
        assert bus is not None  # connected
        original = bus.send

        def send(msg: can.Message, timeout: float | None = None) -> None:
            original(msg, timeout)
            self.sent[who] += 1

        bus.send = send  # type: ignore[method-assign]

    def at(self, t: float) -> None:
        """Sleep until t seconds after the scenario start."""
        delay = self.t0 + t - time.perf_counter()
        if delay > 0:
            time.sleep(delay)

    # -- slaves ------------------------------------------------------------
    def add_slave(
        self,
        node_id: int,
        heartbeat_ms: int = HEARTBEAT_MS,
        *,
        gated_pdo: bool = True,
        ignore_cs: tuple[int, ...] = (),
        guard_responder: bool = False,
        repeat_toggle_at: int | None = None,
        consumer_entries: int = 0,
        ignore_1017_write: bool = False,
    ) -> Slave:
        network = canopen.Network()
        network.NOTIFIER_CYCLE = 0.1
        node = canopen.LocalNode(node_id, build_od(node_id, heartbeat_ms, consumer_entries))
        slave = Slave(node_id, node, network, gated_pdo=gated_pdo, ignore_cs=frozenset(ignore_cs))

        # canopen's LocalNode registers NmtSlave.on_write as a write callback:
        # an SDO write of 1017h (re)starts its heartbeat at the new period.
        # A faulty firmware that ignores the written value: take it out. The
        # SDO server still stores the value and confirms the download (60h).
        if ignore_1017_write:
            node._write_callbacks.remove(node.nmt.on_write)

        def on_write(index: int, subindex: int, od: object, data: bytes) -> None:
            """Runs after canopen's own callbacks: note what the stack did."""
            task = node.nmt._send_task
            slave.writes.append(
                f"node {node_id} SDO server: write {index:04X}h:{subindex:02X} = "
                f"{bytes(data).hex(' ')} at t0+{time.perf_counter() - self.t0:.3f}s; "
                f"heartbeat task now "
                + (f"{task.period * 1000:.0f} ms" if task is not None else "none")
            )

        node.add_write_callback(on_write)

        # Wrap the NMT command handler *before* add_node() subscribes it:
        # counts processed commands, and lets a faulty firmware drop some.
        original: Callable[[int, bytearray, float], None] = node.nmt.on_command

        def on_command(can_id: int, data: bytearray, timestamp: float) -> None:
            if len(data) >= 2 and data[1] in (0, node_id) and data[0] in slave.ignore_cs:
                pass  # faulty firmware: command silently dropped
            else:
                original(can_id, data, timestamp)
            with slave.cond:
                slave.processed += 1
                slave.cond.notify_all()

        node.nmt.on_command = on_command  # type: ignore[method-assign]
        network.add_node(node)
        if guard_responder:
            slave.responder = _GuardResponder(slave, repeat_toggle_at)
            # any can.Listener will do; canopen's annotation names its own subclass
            network.listeners.append(slave.responder)  # type: ignore[arg-type]
        network.connect(interface="virtual", channel=self.vchannel, receive_own_messages=False)
        self._count_sends(network.bus, f"node{node_id}")
        node.tpdo.read(from_od=True)
        self.slaves[node_id] = slave
        self.master.add_node(node_id, build_od(node_id, heartbeat_ms, consumer_entries))
        return slave

    def boot(self, node_id: int) -> None:
        """Power-on of a LocalNode: boot-up (00h), then PRE-OPERATIONAL.

        canopen sends the boot-up only on the transition to INITIALISING;
        the transition to PRE-OPERATIONAL starts the heartbeat producer
        (1017h), whose first frame python-can sends at once."""
        node = self.slaves[node_id].node
        node.nmt.state = "INITIALISING"
        node.nmt.state = "PRE-OPERATIONAL"

    # -- master ------------------------------------------------------------
    def nmt(self, cs: int, node_id: int, wait: bool = True) -> None:
        """Send an NMT command from the master (canopen NmtMaster).

        Holds the PDO lock until every addressed slave has processed the
        frame, so no gated TPDO can slip out after a state-leaving command.
        """
        targets = [s for s in self.slaves.values() if node_id in (0, s.node_id)]
        with self.pdo_lock:
            before = {s.node_id: s.processed for s in targets}
            if node_id == 0:
                self.master.nmt.send_command(cs)
            else:
                self.master[node_id].nmt.send_command(cs)
            if wait:
                for s in targets:
                    with s.cond:

                        def processed(s: Slave = s) -> bool:
                            return s.processed > before[s.node_id]

                        s.cond.wait_for(processed, 1.0)

    def sdo_read(self, node_id: int, index: int, subindex: int) -> bytes:
        data = self.master[node_id].sdo.upload(index, subindex)
        self.notes.append(
            f"SDO upload {index:04X}h:{subindex:02X} from node {node_id} -> {data.hex(' ')}"
        )
        return data

    def remote(self, node_id: int) -> canopen.RemoteNode:
        """The master's view of a node."""
        node = self.master[node_id]
        assert isinstance(node, canopen.RemoteNode)
        return node

    def sdo_write(self, node_id: int, index: int, subindex: int | None, value: int) -> None:
        """Expedited SDO download through canopen's SDO client (``.raw = value``).

        The master's object dictionary has the object's data type, so canopen
        sends e.g. ``2B 17 10 00 64 00 00 00`` for 1017h = 100 (UNSIGNED16)
        and waits for the server's ``60 ...`` confirmation."""
        obj = self.master[node_id].sdo[index]
        if subindex is not None:
            assert isinstance(obj, (SdoArray, SdoRecord))
            obj = obj[subindex]
        assert isinstance(obj, SdoVariable)
        obj.raw = value
        self.notes.append(
            f"SDO download {index:04X}h:{subindex or 0:02X} = 0x{value:X} to node "
            f"{node_id} confirmed at t0+{time.perf_counter() - self.t0:.3f}s"
        )

    # -- PDO scheduler -----------------------------------------------------
    def start_pdo_scheduler(self) -> None:
        self._pdo_thread = threading.Thread(target=self._pdo_loop, name="pdo", daemon=True)
        self._pdo_thread.start()

    def _pdo_loop(self) -> None:
        k = 0
        while not self._stop.is_set():
            due = self.t0 + PDO_PHASE + k * PDO_PERIOD
            k += 1
            delay = due - time.perf_counter()
            if delay > 0 and self._stop.wait(delay):
                break
            with self.pdo_lock:
                for node_id in sorted(self.slaves):
                    s = self.slaves[node_id]
                    if not s.gated_pdo or s.silent or s.node.nmt.state != "OPERATIONAL":
                        continue
                    s.counter = (s.counter + 1) & 0xFFFF
                    tpdo = s.node.tpdo[1]
                    tpdo["Counter"].raw = s.counter
                    tpdo["Analogue input"].raw = 1000 + 10 * node_id
                    tpdo.transmit()

    # -- shutdown and output ---------------------------------------------
    def finish(self) -> list[can.Message]:
        """Stop every producer at once, then stop recording."""
        self._stop.set()
        if self._pdo_thread is not None:
            self._pdo_thread.join()
        for node_id in self.slaves:
            self.remote(node_id).nmt.stop_node_guarding()
        for s in self.slaves.values():
            s.node.nmt.stop_heartbeat()
            s.node.tpdo[1].stop()
        time.sleep(0.15)  # let cyclic threads notice .stopped, drain queues
        for s in self.slaves.values():
            s.network.disconnect()
        self.master.disconnect()
        self.rec_notifier.stop()
        self.rec_bus.shutdown()

        for s in self.slaves.values():
            self.notes.extend(s.writes)
        frames = list(self.collector.frames)
        out_of_order = sum(1 for a, b in pairwise(frames) if b.timestamp < a.timestamp)
        frames.sort(key=lambda m: m.timestamp)  # stable: bus order = send time
        total_sent = sum(self.sent.values())
        keys = [(m.timestamp, m.arbitration_id, m.is_remote_frame, bytes(m.data)) for m in frames]
        dupes = len(keys) - len(set(keys))
        if total_sent != len(frames) or dupes:
            raise RuntimeError(
                f"{self.name}: sent {total_sent} frames "
                f"({dict(self.sent)}), recorded {len(frames)}, "
                f"{dupes} duplicates"
            )
        self.notes.append(
            f"sent {total_sent} = recorded {len(frames)}, duplicates 0, "
            f"arrivals out of timestamp order {out_of_order}"
        )
        return frames


def write_logs(frames: list[can.Message], outdir: Path, name: str) -> list[Path]:
    """Write one recording with python-can's own writers."""
    log_path, asc_path = outdir / f"{name}.log", outdir / f"{name}.asc"
    log_writer = can.CanutilsLogWriter(log_path, channel=LOG_CHANNEL)
    asc_writer = can.ASCWriter(asc_path, channel=1)
    for msg in frames:
        out = can.Message(
            timestamp=msg.timestamp,
            arbitration_id=msg.arbitration_id,
            is_extended_id=msg.is_extended_id,
            is_remote_frame=msg.is_remote_frame,
            dlc=msg.dlc,
            data=None if msg.is_remote_frame else msg.data,
            is_rx=True,
            channel=None,
        )
        log_writer.on_message_received(out)
        asc_writer.on_message_received(out)
    log_writer.stop()
    asc_writer.stop()
    return [log_path, asc_path]


# --------------------------------------------------------------------------
# Scenarios
# --------------------------------------------------------------------------


def scenario_healthy(b: Bench) -> None:
    for nid in (2, 3, 4):
        b.add_slave(nid)
    b.start_pdo_scheduler()
    for i, nid in enumerate((2, 3, 4)):
        b.at(BOOT_AT + 0.010 * i)
        b.boot(nid)
    b.at(0.560)
    b.sdo_read(2, 0x1018, 1)  # identity while PRE-OPERATIONAL
    b.at(1.060)
    b.nmt(CS_START, 0)  # 01 00
    b.at(2.060)
    b.nmt(CS_PREOP, 3)  # 80 03
    b.at(3.060)
    b.nmt(CS_START, 3)  # 01 03
    b.at(3.560)
    b.sdo_read(2, 0x1017, 0)  # heartbeat time while OPERATIONAL
    b.at(4.560)
    b.nmt(CS_STOP, 0)  # 02 00
    b.at(5.060)


def scenario_heartbeat_loss(b: Bench) -> None:
    for nid in (2, 3):
        b.add_slave(nid)
    b.start_pdo_scheduler()
    for i, nid in enumerate((2, 3)):
        b.at(BOOT_AT + 0.010 * i)
        b.boot(nid)
    b.at(0.560)
    b.nmt(CS_START, 0)
    b.at(1.560)
    s3 = b.slaves[3]
    with b.pdo_lock:  # node 3 drops off the bus
        s3.silent = True
        s3.node.nmt.stop_heartbeat()
    b.notes.append(f"node 3 silent from t0+{time.perf_counter() - b.t0:.3f}s")
    b.at(2.610)  # back, same heartbeat phase (10 ms)
    with b.pdo_lock:
        s3.silent = False
        s3.node.nmt.start_heartbeat(HEARTBEAT_MS)
    b.notes.append(f"node 3 back at t0+{time.perf_counter() - b.t0:.3f}s")
    b.at(4.060)


def scenario_pdo_preop(b: Bench) -> None:
    b.add_slave(2, gated_pdo=False)  # starts TPDO1 itself, ignores NMT state
    b.add_slave(3)
    b.start_pdo_scheduler()
    for i, nid in enumerate((2, 3)):
        b.at(BOOT_AT + 0.010 * i)
        b.boot(nid)
    b.at(0.135)  # node 2's application: canopen PdoMap.start()
    tpdo = b.slaves[2].node.tpdo[1]
    tpdo["Counter"].raw = 0x0002
    tpdo["Analogue input"].raw = 1020
    tpdo.start(PDO_PERIOD)
    b.at(1.060)
    b.nmt(CS_START, 0)
    b.at(3.060)


def scenario_guard_toggle(b: Bench) -> None:
    b.add_slave(5, heartbeat_ms=0, guard_responder=True, repeat_toggle_at=5)
    b.add_slave(6, heartbeat_ms=0, guard_responder=True)
    b.start_pdo_scheduler()
    for i, nid in enumerate((5, 6)):
        b.at(BOOT_AT + 0.010 * i)
        b.boot(nid)
    b.at(0.560)
    b.remote(5).nmt.start_node_guarding(0.1)  # RTR 705h every 100 ms
    b.at(0.570)
    b.remote(6).nmt.start_node_guarding(0.1)  # RTR 706h every 100 ms
    b.at(1.010)
    b.nmt(CS_START, 0)
    b.at(3.010)


def scenario_ignored_command(b: Bench) -> None:
    b.add_slave(2)
    b.add_slave(4, ignore_cs=(CS_START,))  # firmware drops "start"
    b.start_pdo_scheduler()
    for i, nid in enumerate((2, 4)):
        b.at(BOOT_AT + 0.010 * i)
        b.boot(nid)
    b.at(0.560)
    b.nmt(CS_START, 2)  # 01 02: obeyed
    b.at(1.060)
    b.nmt(CS_START, 4)  # 01 04: ignored
    b.at(3.060)


def scenario_reset_no_bootup(b: Bench) -> None:
    for nid in (2, 3):
        b.add_slave(nid)
    b.start_pdo_scheduler()
    for i, nid in enumerate((2, 3)):
        b.at(BOOT_AT + 0.010 * i)
        b.boot(nid)
    b.at(0.560)
    b.nmt(CS_START, 0)
    b.at(1.560)
    sent = time.perf_counter()
    b.nmt(CS_RESET_NODE, 3)  # 81 03
    try:
        b.remote(3).nmt.wait_for_bootup(timeout=1.0)
        b.notes.append(
            "master wait_for_bootup() returned after "
            f"{(time.perf_counter() - sent) * 1000:.0f} ms "
            f"(node 3 state now {b.slaves[3].node.nmt.state})"
        )
    except canopen.nmt.NmtError as exc:
        b.notes.append(f"master wait_for_bootup() failed: {exc}")
    b.at(3.560)


def _configure_at_boot(b: Bench, consumer_ms: int) -> None:
    """Boot nodes 2 and 3, then the master configures them over SDO.

    Node 2 gets 1017h = 100 at 0.200 (its heartbeat phase becomes 0 ms,
    like a boot at 0.100 would give), node 3 at 0.210 (phase 10 ms). Then
    node 2's consumer entry 1016h:01 = node 3, ``consumer_ms``."""
    for i, nid in enumerate((2, 3)):
        b.at(BOOT_AT + 0.010 * i)
        b.boot(nid)
    b.at(0.200)
    b.sdo_write(2, 0x1017, None, HEARTBEAT_MS)  # 2B 17 10 00 64 00 00 00
    b.at(0.210)
    b.sdo_write(3, 0x1017, None, HEARTBEAT_MS)
    b.at(0.260)
    b.sdo_write(2, 0x1016, 1, (3 << 16) | consumer_ms)  # 23 16 10 01 .. .. 03 00


SDO_CONSUMER_MS = 250  # sdo_config: node 2 watches node 3 with 250 ms
IGNORED_CONSUMER_MS = 1000  # ignored_1017: longer than node 3's real 500 ms
IGNORED_HB_MS = 500  # ignored_1017: node 3's fixed firmware period


def scenario_sdo_config(b: Bench) -> None:
    b.add_slave(2, heartbeat_ms=0, consumer_entries=1)
    b.add_slave(3, heartbeat_ms=0)
    b.start_pdo_scheduler()
    _configure_at_boot(b, SDO_CONSUMER_MS)
    b.at(1.060)
    b.nmt(CS_START, 0)  # 01 00
    b.at(3.060)


def scenario_ignored_1017(b: Bench) -> None:
    b.add_slave(2, heartbeat_ms=0, consumer_entries=1)
    b.add_slave(3, heartbeat_ms=IGNORED_HB_MS, ignore_1017_write=True)
    b.start_pdo_scheduler()
    _configure_at_boot(b, IGNORED_CONSUMER_MS)
    b.at(0.560)
    b.sdo_read(3, 0x1017, 0)  # node 3 reports the written 100 ms
    b.at(1.060)
    b.nmt(CS_START, 0)  # 01 00
    b.at(5.060)


SCENARIOS: dict[str, Callable[[Bench], None]] = {
    "healthy": scenario_healthy,
    "heartbeat_loss": scenario_heartbeat_loss,
    "pdo_preop": scenario_pdo_preop,
    "guard_toggle": scenario_guard_toggle,
    "ignored_command": scenario_ignored_command,
    "reset_no_bootup": scenario_reset_no_bootup,
    "sdo_config": scenario_sdo_config,
    "ignored_1017": scenario_ignored_1017,
}


# --------------------------------------------------------------------------
# Verification: read the files back with python-can and check the fault
# --------------------------------------------------------------------------


def read_back(path: Path) -> list[can.Message]:
    return [m for m in can.LogReader(str(path))]


def summarize(frames: list[can.Message]) -> str:
    t0 = frames[0].timestamp if frames else 0.0
    by_id: dict[tuple[int, bool], list[can.Message]] = collections.defaultdict(list)
    for m in frames:
        by_id[(m.arbitration_id, m.is_remote_frame)].append(m)
    lines = []
    for (cid, rtr), ms in sorted(by_id.items()):
        extra = ""
        if 0x700 < cid < 0x780 and not rtr:
            extra = " bytes " + ",".join(sorted({f"{m.data[0]:02X}" for m in ms}))
        elif cid == 0:
            extra = " cmds " + ",".join(m.data.hex(" ") for m in ms)
        lines.append(
            f"    {cid:03X}{'(RTR)' if rtr else '     '} n={len(ms):4d} "
            f"first={ms[0].timestamp - t0:7.3f} last={ms[-1].timestamp - t0:7.3f}{extra}"
        )
    return "\n".join(lines)


def _nmt(frames: list[can.Message], cs: int, nid: int) -> list[can.Message]:
    return [m for m in frames if m.arbitration_id == 0 and bytes(m.data) == bytes([cs, nid])]


def _ec(frames: list[can.Message], nid: int) -> list[can.Message]:
    return [m for m in frames if m.arbitration_id == 0x700 + nid and not m.is_remote_frame]


def _tpdo(frames: list[can.Message], nid: int) -> list[can.Message]:
    return [m for m in frames if m.arbitration_id == 0x180 + nid]


def _sdo_exchange(frames: list[can.Message], nid: int,
                  request: bytes) -> tuple[can.Message, can.Message]:
    """The SDO request on 600h+N with exactly these bytes and the server's
    next frame on 580h+N (its confirmation)."""
    req = next(m for m in frames if m.arbitration_id == 0x600 + nid and bytes(m.data) == request)
    resp = next(
        m for m in frames if m.arbitration_id == 0x580 + nid and m.timestamp >= req.timestamp
    )
    return req, resp


def _intervals(ms: list[can.Message]) -> list[float]:
    return [b.timestamp - a.timestamp for a, b in pairwise(ms)]


def _hb_config_evidence(
    frames: list[can.Message], nid: int, req: can.Message, resp: can.Message,
    rel: Callable[[can.Message], float],
) -> tuple[list[can.Message], list[float], str]:
    """Node nid's heartbeats (not the boot-up) around its 1017h download.

    Returns the heartbeats after the request, their intervals, and one line
    of evidence: heartbeats before the write, the first one after it (and
    its offset from request and confirmation), intervals after."""
    ec = _ec(frames, nid)
    boot, hbs = ec[0], ec[1:]
    before = [m for m in hbs if m.timestamp < req.timestamp]
    after = [m for m in hbs if m.timestamp >= req.timestamp]
    iv_b, iv_a = _intervals([boot, *before]), _intervals(after)
    first = after[0]
    med = statistics.median(iv_a)
    line = (
        f"node {nid}: boot-up @{rel(boot):.4f}; before the write "
        + (
            f"{len(before)} heartbeat(s), intervals from boot-up "
            + ", ".join(f"{x * 1000:.0f}" for x in iv_b)
            + " ms"
            if before
            else "no heartbeat"
        )
        + f"; first heartbeat after the request {first.data[0]:02X}h @{rel(first):.4f} "
        f"({(first.timestamp - req.timestamp) * 1000:+.2f} ms from the request, "
        f"{(first.timestamp - resp.timestamp) * 1000:+.2f} ms from the confirmation); "
        f"then {len(iv_a)} intervals min/median/max "
        f"{min(iv_a) * 1000:.1f}/{med * 1000:.1f}/{max(iv_a) * 1000:.1f} ms "
        f"until {rel(after[-1]):.3f}"
    )
    return after, iv_a, line


def check_pdo_gating(frames: list[can.Message], nids: tuple[int, ...], t0: float) -> list[str]:
    """No TPDO of nid outside [start cmd, next non-start cmd to nid)."""
    problems = []
    for nid in nids:
        state = "PRE"
        cmd_iter = [m for m in frames if m.arbitration_id == 0 and m.data[1] in (0, nid)]
        events = sorted(
            [(m.timestamp, 0, m) for m in cmd_iter]
            + [(m.timestamp, 1, m) for m in _tpdo(frames, nid)],
            key=lambda e: (e[0], e[1]),
        )
        for ts, kind, m in events:
            if kind == 0:
                state = {CS_START: "OP", CS_STOP: "STOP"}.get(m.data[0], "PRE")
            elif state != "OP":
                problems.append(f"node {nid}: TPDO at {ts - t0:.3f} while {state}")
    return problems


def _check_bootups_first(frames: list[can.Message]) -> None:
    """Common to every sample: each heartbeat producer's first frame is its boot-up."""
    for nid in range(1, 128):
        ec = _ec(frames, nid)
        if ec:
            assert ec[0].data[0] == 0x00, f"node {nid}: first 700h+N frame is not a boot-up"


def _verify_healthy(name: str, frames: list[can.Message], t0: float,
                    rel: Callable[[can.Message], float], ev: list[str]) -> None:
    problems = check_pdo_gating(frames, (2, 3, 4), t0)
    assert not problems, problems
    stop = _nmt(frames, CS_STOP, 0)[0]
    hb_all = [m for m in frames if 0x700 < m.arbitration_id < 0x780]
    late = [
        m
        for m in frames
        if m.timestamp > stop.timestamp
        and (0x580 < m.arbitration_id < 0x600 or 0x180 < m.arbitration_id < 0x200)
    ]
    assert not late, "PDO/SDO after stop-all"
    for nid in (2, 3, 4):
        hb = _ec(frames, nid)
        gaps = [b.timestamp - a.timestamp for a, b in pairwise(hb)]
        assert max(gaps) < 0.130, f"node {nid} heartbeat gap {max(gaps):.3f}"
    p3 = _tpdo(frames, 3)
    pre = _nmt(frames, CS_PREOP, 3)[0]
    restart = _nmt(frames, CS_START, 3)[0]
    before = [m for m in p3 if m.timestamp < pre.timestamp]
    after = [m for m in p3 if m.timestamp > restart.timestamp]
    ev.append(
        f"node 3: last TPDO before 80 03 at {rel(before[-1]):.3f}, "
        f"80 03 at {rel(pre):.3f}, 01 03 at {rel(restart):.3f}, "
        f"next TPDO at {rel(after[0]):.3f}; no TPDO in between"
    )
    sdo = [m for m in frames if m.arbitration_id in (0x602, 0x582)]
    ev.append(
        "SDO: "
        + "; ".join(f"{m.arbitration_id:03X} {m.data.hex(' ')} @{rel(m):.3f}" for m in sdo)
    )
    ev.append(
        f"stop-all at {rel(stop):.3f}; last TPDO at "
        f"{max(rel(m) for m in frames if 0x180 < m.arbitration_id < 0x200):.3f}; "
        f"04h heartbeats after it: {sum(1 for m in hb_all if m.data[0] == 4)}"
    )


def _verify_heartbeat_loss(name: str, frames: list[can.Message], t0: float,
                           rel: Callable[[can.Message], float], ev: list[str]) -> None:
    hb = _ec(frames, 3)
    gaps = [(b.timestamp - a.timestamp, a, b) for a, b in pairwise(hb)]
    big = [g for g in gaps if g[0] > 0.150]
    assert len(big) == 1 and big[0][0] > 1.0, f"gaps {[round(g[0], 3) for g in big]}"
    g, a, b_ = big[0]
    ev.append(
        f"node 3 heartbeat gap {g * 1000:.0f} ms: last {a.data[0]:02X}h at "
        f"{rel(a):.3f}, next {b_.data[0]:02X}h at {rel(b_):.3f} "
        f"(~{round(g / 0.1) - 1} periods missing); H001 due at {rel(a) + 0.150:.3f}"
    )
    mine = [m for m in frames if m.arbitration_id in (0x183, 0x583, 0x83, 0x703)]
    before = [m for m in mine if m.timestamp < b_.timestamp][-1]
    silent = b_.timestamp - before.timestamp
    assert silent > 1.0, f"node 3 silent for only {silent:.3f} s"
    ev.append(
        f"node 3 completely silent from {rel(before):.3f} "
        f"({before.arbitration_id:03X} {before.data.hex(' ')}) to {rel(b_):.3f}: "
        f"{silent * 1000:.0f} ms; TPDOs resume at "
        f"{rel(next(m for m in _tpdo(frames, 3) if m.timestamp > b_.timestamp)):.3f}"
    )
    hb2 = _ec(frames, 2)
    assert max(y.timestamp - x.timestamp for x, y in pairwise(hb2)) < 0.130
    assert not check_pdo_gating(frames, (2, 3), t0)
    ev.append("node 2: heartbeat regular (max gap < 130 ms) throughout")


def _verify_pdo_preop(name: str, frames: list[can.Message], t0: float,
                      rel: Callable[[can.Message], float], ev: list[str]) -> None:
    start = _nmt(frames, CS_START, 0)[0]
    early = [m for m in _tpdo(frames, 2) if m.timestamp < start.timestamp]
    assert len(early) >= 10, len(early)
    boot2 = _ec(frames, 2)[0]
    hb2 = {f"{m.data[0]:02X}" for m in _ec(frames, 2) if m.timestamp < start.timestamp}
    ev.append(
        f"node 2 boot-up at {rel(boot2):.3f}; {len(early)} TPDO1 182h frames "
        f"{rel(early[0]):.3f}..{rel(early[-1]):.3f} (data {early[0].data.hex(' ')}) "
        f"before NMT 01 00 at {rel(start):.3f}; node 2 heartbeat then "
        f"{'/'.join(sorted(hb2))}"
    )
    assert not check_pdo_gating(frames, (3,), t0)
    ev.append(f"node 3: {len(_tpdo(frames, 3))} TPDOs, all after the start command")


def _verify_guard_toggle(name: str, frames: list[can.Message], t0: float,
                         rel: Callable[[can.Message], float], ev: list[str]) -> None:
    for nid in (5, 6):
        rtr = [m for m in frames if m.arbitration_id == 0x700 + nid and m.is_remote_frame]
        resp = [m for m in _ec(frames, nid)][1:]  # skip boot-up
        assert len(rtr) == len(resp), (nid, len(rtr), len(resp))
        assert all(m.dlc == 0 for m in rtr), "RTR DLC"
        toggles = [m.data[0] >> 7 for m in resp]
        repeats = [i for i in range(1, len(toggles)) if toggles[i] == toggles[i - 1]]
        seq = " ".join(f"{m.data[0]:02X}" for m in resp[:8])
        if nid == 5:
            assert toggles[0] == 0 and repeats == [4], (toggles, repeats)
            r = resp[4]
            ev.append(
                f"node 5: {len(rtr)} RTRs (DLC 0) / {len(resp)} responses; "
                f"first responses {seq} ...; response #5 at {rel(r):.3f} = "
                f"{r.data[0]:02X}h repeats toggle {toggles[4]} of #4 "
                f"({resp[3].data[0]:02X}h at {rel(resp[3]):.3f})"
            )
        else:
            assert toggles[0] == 0 and not repeats, (toggles, repeats)
            ev.append(
                f"node 6: {len(rtr)} RTRs / {len(resp)} responses, toggles "
                f"alternate from 0: {seq} ..."
            )
    assert not [
        m
        for m in frames
        if m.arbitration_id in (0x705, 0x706)
        and not m.is_remote_frame
        and m.data[0] & 0x7F not in (0, 0x7F, 5)
    ]


def _verify_ignored_command(name: str, frames: list[can.Message], t0: float,
                            rel: Callable[[can.Message], float], ev: list[str]) -> None:
    cmd = _nmt(frames, CS_START, 4)[0]
    after = [m for m in _ec(frames, 4) if m.timestamp > cmd.timestamp]
    assert after and all(m.data[0] == 0x7F for m in after)
    ev.append(
        f"01 04 at {rel(cmd):.3f}; node 4 then sends {len(after)} heartbeats "
        f"all 7Fh, {rel(after[0]):.3f}..{rel(after[-1]):.3f} "
        f"({(after[-1].timestamp - cmd.timestamp) * 1000:.0f} ms after the command)"
    )
    c2 = _nmt(frames, CS_START, 2)[0]
    first05 = next(m for m in _ec(frames, 2) if m.data[0] == 5)
    ev.append(
        f"01 02 at {rel(c2):.3f}; node 2 reports 05h at {rel(first05):.3f} "
        f"(+{(first05.timestamp - c2.timestamp) * 1000:.0f} ms)"
    )
    assert not _tpdo(frames, 4)
    assert not check_pdo_gating(frames, (2,), t0)


def _verify_reset_no_bootup(name: str, frames: list[can.Message], t0: float,
                            rel: Callable[[can.Message], float], ev: list[str]) -> None:
    rst = _nmt(frames, CS_RESET_NODE, 3)[0]
    after = [
        m
        for m in frames
        if m.timestamp > rst.timestamp and m.arbitration_id in (0x703, 0x183, 0x583, 0x83)
    ]
    assert after and all(m.arbitration_id == 0x703 and m.data[0] == 0 for m in after)
    zeros = after
    iv = [b.timestamp - a.timestamp for a, b in pairwise(zeros)]
    ev.append(
        f"81 03 at {rel(rst):.3f}; node 3 then sends only 703h 00h: "
        f"{len(zeros)} frames {rel(zeros[0]):.3f}..{rel(zeros[-1]):.3f}, "
        f"interval {min(iv) * 1000:.0f}..{max(iv) * 1000:.0f} ms; "
        f"no 7Fh, no TPDO after the reset"
    )
    before = [m for m in _ec(frames, 3) if m.timestamp < rst.timestamp]
    ev.append(
        f"node 3 before the reset: {len(before)} frames "
        f"{'/'.join(sorted({f'{m.data[0]:02X}' for m in before}))}; "
        f"first frame of node 3 after 81 03: "
        f"{after[0].arbitration_id:03X} {after[0].data.hex()} at +"
        f"{(after[0].timestamp - rst.timestamp) * 1000:.0f} ms"
    )
    assert not check_pdo_gating(frames, (2,), t0)


def _verify_sdo_config_ignored_1017(name: str, frames: list[can.Message], t0: float,
                                    rel: Callable[[can.Message], float], ev: list[str]) -> None:
    consumer_ms = SDO_CONSUMER_MS if name == "sdo_config" else IGNORED_CONSUMER_MS
    aborts = [m for m in frames if 0x580 < m.arbitration_id < 0x600 and m.data[0] == 0x80]
    assert not aborts, f"SDO aborts {[m.data.hex(' ') for m in aborts]}"
    hb_1017 = bytes([0x2B, 0x17, 0x10, 0x00, HEARTBEAT_MS & 0xFF, HEARTBEAT_MS >> 8, 0, 0])
    entry = (3 << 16) | consumer_ms
    c_1016 = bytes([0x23, 0x16, 0x10, 0x01]) + entry.to_bytes(4, "little")
    exchanges = {}
    for nid, request in ((2, hb_1017), (3, hb_1017), (2, c_1016)):
        req, resp = _sdo_exchange(frames, nid, request)
        assert bytes(resp.data) == bytes([0x60]) + request[1:4] + bytes(4), (
            f"node {nid}: confirmation {resp.data.hex(' ')}"
        )
        assert resp.timestamp - req.timestamp < 0.010
        exchanges[(nid, request[1])] = (req, resp)
        ev.append(
            f"SDO node {nid}: {req.arbitration_id:03X} {req.data.hex(' ')} @{rel(req):.4f}"
            f" -> {resp.arbitration_id:03X} {resp.data.hex(' ')} @{rel(resp):.4f}"
            f" (+{(resp.timestamp - req.timestamp) * 1000:.2f} ms)"
        )
    producers = (2, 3) if name == "sdo_config" else (2,)
    for nid in producers:  # 1017h = 0 at boot, heartbeat from the write on
        req, resp = exchanges[(nid, 0x17)]
        after, iv, line = _hb_config_evidence(frames, nid, req, resp, rel)
        ev.append(line)
        ec = _ec(frames, nid)
        assert ec[1] is after[0], f"node {nid}: heartbeat before the 1017h write"
        assert abs(after[0].timestamp - resp.timestamp) < 0.005
        assert after[0].timestamp - ec[0].timestamp < 0.150, "boot-up to heartbeat gap"
        assert all(0.070 < x < 0.130 for x in iv), f"node {nid} intervals {iv}"
    if name == "ignored_1017":
        req, resp = exchanges[(3, 0x17)]
        after, iv, line = _hb_config_evidence(frames, nid=3, req=req, resp=resp, rel=rel)
        ev.append(line)
        iv_all = _intervals(_ec(frames, 3)[1:])
        assert all(0.450 < x < 0.550 for x in iv_all), f"node 3 intervals {iv_all}"
        held = [m for m in after if m.timestamp > resp.timestamp]
        assert len(held) >= 6 and held[-1].timestamp - resp.timestamp >= 4.0, (
            len(held),
            held[-1].timestamp - resp.timestamp,
        )
        med = statistics.median(_intervals(held))
        up = [m for m in frames if m.arbitration_id == 0x583 and m.data[0] == 0x4B]
        assert up and bytes(up[0].data[:6]) == bytes.fromhex("4b1710006400")
        ev.append(
            f"node 3 after the confirmed 1017h = {HEARTBEAT_MS} ms: {len(held)} heartbeats "
            f"over {held[-1].timestamp - resp.timestamp:.3f} s, median interval "
            f"{med * 1000:.1f} ms; SDO upload of 1017h answers "
            f"{up[0].data.hex(' ')} @{rel(up[0]):.4f} (the written value)"
        )
    assert not check_pdo_gating(frames, (2, 3), t0)
    ev.append(
        f"TPDOs: 182h {len(_tpdo(frames, 2))}, 183h {len(_tpdo(frames, 3))}, all "
        f"after 01 00 at {rel(_nmt(frames, CS_START, 0)[0]):.3f}"
    )


def verify(name: str, frames: list[can.Message]) -> list[str]:
    """Check the intended fault (and nothing of the other kinds) is present.
    Returns a list of evidence lines; raises AssertionError on failure."""
    t0 = frames[0].timestamp
    ev: list[str] = []

    def rel(m: can.Message) -> float:
        return m.timestamp - t0

    _check_bootups_first(frames)

    verify = {
        "healthy": _verify_healthy, "heartbeat_loss": _verify_heartbeat_loss,
        "pdo_preop": _verify_pdo_preop, "guard_toggle": _verify_guard_toggle,
        "ignored_command": _verify_ignored_command, "reset_no_bootup": _verify_reset_no_bootup,
        "sdo_config": _verify_sdo_config_ignored_1017,
        "ignored_1017": _verify_sdo_config_ignored_1017,
    }.get(name)
    if verify is not None:
        verify(name, frames, t0, rel, ev)
    return ev


# --------------------------------------------------------------------------


def check_files(
    name: str, outdir: Path, say: Callable[[str], None], recorded: int | None = None
) -> int:
    """Read <name>.log and <name>.asc back with can.LogReader, compare them,
    print a per-CAN-ID summary and verify the scenario's fault. Returns the
    number of failures."""
    failures = 0
    paths = [outdir / f"{name}.log", outdir / f"{name}.asc"]
    back = {p.suffix: read_back(p) for p in paths}
    for p in paths:
        say(f"   {p.name}: {len(back[p.suffix])} frames, {p.stat().st_size} bytes")
    log, asc = back[".log"], back[".asc"]
    if len(log) != len(asc) or (recorded is not None and len(log) != recorded):
        say(f"   FAIL: frame counts differ: recorded {recorded}, .log {len(log)}, .asc {len(asc)}")
        failures += 1
    same = all(
        (a.arbitration_id, a.is_remote_frame, bytes(a.data or b""))
        == (b.arbitration_id, b.is_remote_frame, bytes(b.data or b""))
        and abs((a.timestamp - log[0].timestamp) - (b.timestamp - asc[0].timestamp)) < 2e-6
        for a, b in zip(log, asc, strict=False)
    )
    if not same:
        say("   FAIL: .log and .asc frames differ")
        failures += 1
    say(summarize(log))
    try:
        for line in verify(name, log):
            say(f"   evidence: {line}")
        say("   OK: intended behaviour present")
    except AssertionError as exc:
        say(f"   FAIL: {exc!r}")
        failures += 1
    return failures


# --------------------------------------------------------------------------
# Device files: DCFs of the healthy network's slaves, and network.toml
# --------------------------------------------------------------------------

DCF_NODES = (2, 3, 4)  # the slaves of ``healthy``

NETWORK_TOML = """\
# nmtcheck network description (SPEC section 6) for healthy.log / healthy.asc.
# Written by record_samples.py. Each node's values (1017h = 100 ms heartbeat,
# 100Ch/100Dh, TPDO1 COB-ID 180h+N) come from its DCF, which canopen's
# export_od() wrote from the object dictionary the script gives that slave.
#
#   nmtcheck check samples/healthy.log --network samples/network.toml
""" + "".join(f'\n[nodes.{nid}]\ndcf = "devices/node{nid}.dcf"\n' for nid in DCF_NODES)


def _od_entries(
    od: od_mod.ObjectDictionary,
) -> dict[tuple[int, int], tuple[int | None, str, int | None]]:
    """(index, subindex) -> (data type, access, value) of every variable.
    The value is the DCF's ParameterValue if it has one, else DefaultValue."""
    out = {}
    for index in od:
        obj = od[index]
        members = [obj] if isinstance(obj, od_mod.ODVariable) else [obj[s] for s in obj]
        for var in members:
            value = var.value if getattr(var, "value", None) is not None else var.default
            out[(index, var.subindex)] = (var.data_type, var.access_type, value)
    return out


def export_dcfs(outdir: Path, say: Callable[[str], None]) -> int:
    """Export one DCF per slave of ``healthy`` with canopen's own exporter,
    write network.toml, then check them (:func:`check_dcfs`)."""
    devdir = outdir / "devices"
    devdir.mkdir(parents=True, exist_ok=True)
    for nid in DCF_NODES:
        path = devdir / f"node{nid}.dcf"
        canopen.export_od(build_od(nid, HEARTBEAT_MS), str(path), doc_type="dcf")
    (outdir / "network.toml").write_text(NETWORK_TOML)
    return check_dcfs(outdir, say)


def check_dcfs(outdir: Path, say: Callable[[str], None]) -> int:
    """Import every DCF back with ``canopen.import_od``: same objects, data
    types, access and values as :func:`build_od`, node-ID from
    [DeviceComissioning], 1017h = 100. network.toml must name them all."""
    say("== devices (DCF) and network.toml")
    failures = 0
    for nid in DCF_NODES:
        path = outdir / "devices" / f"node{nid}.dcf"
        try:
            od = canopen.import_od(str(path))
            got, want = _od_entries(od), _od_entries(build_od(nid, HEARTBEAT_MS))
            diff = sorted(k for k in set(got) | set(want) if got.get(k) != want.get(k))
            assert not diff, [
                (f"{i:04X}:{s:02X}", got.get((i, s)), want.get((i, s))) for i, s in diff
            ]
            assert od.node_id == nid, f"NodeID {od.node_id}"
            hb = got[(0x1017, 0)][2]
            assert hb == HEARTBEAT_MS, f"1017h = {hb}"
            say(
                f"   {path.parent.name}/{path.name}: {path.stat().st_size} bytes, "
                f"{len(got)} entries as built, NodeID {od.node_id}, "
                f"1017h = {hb} ms, TPDO1 COB-ID {got[(0x1800, 1)][2]:03X}h"
            )
        except (AssertionError, OSError, canopen.ObjectDictionaryError, KeyError) as exc:
            say(f"   FAIL: {path.name}: {exc!r}")
            failures += 1
    try:
        with open(outdir / "network.toml", "rb") as fh:
            nodes = tomllib.load(fh)["nodes"]
        want_nodes = {str(nid): {"dcf": f"devices/node{nid}.dcf"} for nid in DCF_NODES}
        assert nodes == want_nodes, nodes
        say(f"   network.toml: nodes {', '.join(nodes)}, each with its DCF")
    except (AssertionError, OSError, KeyError, tomllib.TOMLDecodeError) as exc:
        say(f"   FAIL: network.toml: {exc!r}")
        failures += 1
    return failures


def run(names: list[str], outdir: Path, quiet: bool, check_only: bool) -> int:
    say = (lambda s: None) if quiet else print
    outdir.mkdir(parents=True, exist_ok=True)
    failures = 0
    started = time.perf_counter()
    for name in names:
        if check_only:
            say(f"== {name}")
            failures += check_files(name, outdir, say)
            continue
        bench = Bench(name)
        t = time.perf_counter()
        try:
            SCENARIOS[name](bench)
        finally:
            frames = bench.finish()
        write_logs(frames, outdir, name)
        say(f"== {name}: {len(frames)} frames recorded in {time.perf_counter() - t:.1f} s")
        for note in bench.notes:
            say(f"   {note}")
        failures += check_files(name, outdir, say, recorded=len(frames))
    say(f"total {time.perf_counter() - started:.1f} s, {failures} failure(s)")
    return 1 if failures else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--outdir",
        type=Path,
        default=Path(__file__).resolve().parent,
        help="where to write <name>.log and <name>.asc (default: this script's folder)",
    )
    parser.add_argument(
        "--only",
        nargs="+",
        choices=list(SCENARIOS),
        metavar="NAME",
        help=f"record only these scenarios ({', '.join(SCENARIOS)})",
    )
    parser.add_argument(
        "--check-only",
        action="store_true",
        help="do not record: re-read and verify the existing files",
    )
    parser.add_argument(
        "--dcf-only",
        action="store_true",
        help="do not record: export devices/node2..4.dcf and write network.toml",
    )
    parser.add_argument("--quiet", action="store_true", help="print nothing")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    say = (lambda s: None) if args.quiet else print
    if args.dcf_only:
        failures = export_dcfs(args.outdir, say)
        say(f"{failures} failure(s)")
        return 1 if failures else 0
    status = run(args.only or list(SCENARIOS), args.outdir, args.quiet, args.check_only)
    if args.only is None:  # a full run also (re)writes or checks the device files
        dcf = check_dcfs if args.check_only else export_dcfs
        if dcf(args.outdir, say):
            status = 1
    return status


if __name__ == "__main__":
    sys.exit(main())
