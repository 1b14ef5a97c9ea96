"""EDS/DCF reading on real files (the shared corpus, the samples, tests/data/devices), and
what the network file takes from them."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from conftest import CORPUS, DATA, SAMPLES, candump, needs_corpus, shared_file

from nmtcheck.errors import UsageError
from nmtcheck.protocol import devicefile
from nmtcheck.protocol.devicefile import load_device_file
from nmtcheck.settings.network import load_network

EDS = CORPUS / "eds"
# the whole EDS/DCF corpus, or without ../shared the permissive files copied to tests/data
EDS_DIR = EDS if EDS.is_dir() else DATA / "corpus" / "eds"
ALL_FILES = sorted([*EDS_DIR.glob("*/*.eds"), *EDS_DIR.glob("*/*.dcf")])
DEVICES = Path(__file__).resolve().parent / "data" / "devices"
LELY_MASTER = DEVICES / "lely_master.dcf"  # compact storage, as Lely's dcfgen writes it
SLAVE = DEVICES / "slave_values.dcf"


@pytest.mark.parametrize("path", ALL_FILES, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_corpus_file_loads(path: Path) -> None:
    values = load_device_file(str(path), 5)
    assert values.path == str(path)


@pytest.mark.parametrize(("name", "key", "value"), [
    ("canopennode/DS301_profile.eds", "emcy_cob_id", 0x85), ("lely/co-gw_txt-master.dcf",
                                                             "nmt_master", True)])
def test_files_canopen_rejects_are_read(name: str, key: str, value: object) -> None:
    """An empty numeric value, a DummyUsage section without all entries: canopen's import
    raises on these; the INI reading takes what the objects give."""
    values = load_device_file(str(shared_file(f"corpus/eds/{name}")), 5)
    assert values.notes == [] and getattr(values, key) == value


def test_values_from_real_files() -> None:
    lely = load_device_file(str(shared_file("corpus/eds/lely/co-nmt-slave.dcf")))
    assert (lely.node_id, lely.heartbeat_ms) == (2, 100.0)  # ParameterValue=100 wins over 0
    pdo = load_device_file(str(shared_file("corpus/eds/lely/co-pdo-transmit.dcf")), 7)
    assert pdo.tpdo_cob_ids == {1: 0x187}  # $NODEID+0x180 resolved with the given node-ID


@needs_corpus  # OreSat's files are GPL-3.0 and e35.eds is 131 kB: not copied to tests/data
def test_values_from_real_files_oresat_and_e35() -> None:
    oresat = load_device_file(str(EDS / "oresat/battery.dcf"), 5)
    assert oresat.heartbeat_ms == 1000.0
    assert oresat.tpdo_cob_ids == {1: 0x185, 2: 0x285, 3: 0x385, 4: 0x485}
    e35 = load_device_file(str(EDS / "python-canopen/e35.eds"), 5)
    assert (e35.guard_time_ms, e35.life_time_factor) == (100.0, 4)
    # a COB-ID with bit 31 set: the PDO is not valid
    assert e35.rpdo_cob_ids[2] is None


def _every_device_file() -> list[Path]:
    found = {*ALL_FILES, *SAMPLES.rglob("*.eds"), *SAMPLES.rglob("*.dcf"),
             *DATA.rglob("*.eds"), *DATA.rglob("*.dcf")}
    return sorted(found)


def _canopen_number(entry: Any) -> int | None:
    """The number canopen's import reads for an entry (its ParameterValue over its
    DefaultValue); None where it reads none, or a `$NODEID` value (canopen substitutes the
    file's NodeID even when that is no node-ID)."""
    for raw_attr, value in (("value_raw", entry.value), ("default_raw", entry.default)):
        raw = getattr(entry, raw_attr, None)  # set by the import only when the key is there
        if raw is not None and str(raw).strip():
            if "$NODEID" in str(raw).upper() or not isinstance(value, int) or isinstance(
                    value, bool):
                return None
            return int(value)
    return None


@pytest.mark.parametrize("path", _every_device_file(),
                         ids=lambda p: f"{p.parent.name}/{p.name}")
def test_used_sections_give_what_the_whole_file_and_canopen_give(
        path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Reading only the sections of USED_OBJECTS gives the values and notes of the whole
    file; and every number canopen's import reads for those objects (the reader nmtcheck
    used until 2026-12) is the number read, where canopen can import the file at all
    (compact storage: canopen ignores `[xxxxValue]`)."""
    import canopen

    for node_id in (None, 5):
        part = load_device_file(str(path), node_id)
        with monkeypatch.context() as patch:
            patch.setattr(devicefile, "_used_text", lambda p: p.read_text(encoding="latin-1"))
            whole = load_device_file(str(path), node_id)
        assert dataclasses.asdict(part) == dataclasses.asdict(whole)
        ini = devicefile._Ini(path)
        nid = node_id or ini.node_id()
        try:
            od = canopen.import_od(str(path), nid)
        except Exception:  # noqa: BLE001 - canopen raises many kinds on messy files
            continue
        compared = 0
        for index in sorted(devicefile.USED_OBJECTS):
            obj = od.get(index)
            if obj is None or ini.compact(index) is not None:
                continue
            entries = obj.subindices.items() if hasattr(obj, "subindices") else [(None, obj)]
            for sub, entry in entries:
                expected = _canopen_number(entry)
                if expected is not None:
                    assert ini.value(index, sub, nid) == expected, (index, sub)
                    compared += 1
        assert compared or not any(od.get(i) is not None for i in devicefile.USED_OBJECTS)


def test_objects_nmtcheck_does_not_use_are_not_parsed(tmp_path: Path) -> None:
    """A device file's manufacturer and profile objects (2000h-9FFFh, most of a big EDS)
    are skipped as lines, never parsed; and canopen (its import alone pulls in python-can,
    asammdf, pandas and sympy where installed: about 200 MB) is not imported."""
    eds = tmp_path / "big.eds"
    lines = ["[DeviceInfo]", "VendorNumber=0x1234", "[1017]", "ParameterName=Producer heartbeat",
             "DataType=0x0006", "AccessType=rw", "DefaultValue=100"]
    for index in range(0x2000, 0x2400):
        lines += [f"[{index:04X}]", "SubNumber=2", "ObjectType=0x9",
                  f"[{index:04X}sub0]", "DataType=0x0005", "DefaultValue=1",
                  f"[{index:04X}sub1]", "DataType=0x0007", "DefaultValue=0x10", "not a key"]
    eds.write_text("\n".join(lines) + "\n")
    ini = devicefile._Ini(eds)
    assert ini.cp.sections() == ["DeviceInfo", "1017"]
    with pytest.raises(KeyError, match="2000h"):
        ini.value(0x2000, 1, None)
    code = ("import sys; from nmtcheck.protocol.devicefile import load_device_file as load; "
            f"v = load({str(eds)!r}, 3); print(v.heartbeat_ms, v.notes, 'canopen' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["100.0", "[]", "False"]


def test_consumer_entry_and_slave_assignment(tmp_path: Path) -> None:
    """A master DCF with 1016h naming node 3 (250 ms) and 1F81h listing nodes 3 and 4."""
    master = tmp_path / "master.dcf"
    master.write_text(
        "[DeviceComissioning]\nNodeID=1\n"
        "[1016]\nSubNumber=2\nObjectType=0x8\n"
        "[1016sub0]\nDataType=0x0005\nAccessType=ro\nDefaultValue=1\n"
        "[1016sub1]\nDataType=0x0007\nAccessType=rw\nDefaultValue=0\nParameterValue=0x000300FA\n"
        "[1F81]\nSubNumber=5\nObjectType=0x8\n"
        "[1F81sub0]\nDataType=0x0005\nAccessType=ro\nDefaultValue=4\n"
        "[1F81sub3]\nDataType=0x0007\nAccessType=rw\nDefaultValue=0x5\n"
        "[1F81sub4]\nDataType=0x0007\nAccessType=rw\nDefaultValue=0x1\n")
    values = load_device_file(str(master), 1)
    assert values.consumers == {3: 250.0}
    assert values.slaves == [3, 4]
    net = tmp_path / "net.toml"
    net.write_text('[nodes.1]\ndcf = "master.dcf"\n[nodes.3]\nheartbeat_ms = 100\n')
    network = load_network(str(net))
    cfg3 = network.nodes[3][0]
    assert (cfg3.consumer_timeout_ms, cfg3.consumer_node, cfg3.heartbeat_ms) == (250.0, 1, 100.0)
    assert [n for n, _ in network.expected()] == [1, 3, 4]


def test_explicit_keys_win_over_the_device_file(tmp_path: Path) -> None:
    net = tmp_path / "net.toml"
    dcf = shared_file("corpus/eds/lely/co-nmt-slave.dcf")
    net.write_text(f'[nodes.2]\ndcf = "{dcf}"\nheartbeat_ms = 250\n')
    assert load_network(str(net)).nodes[2][0].heartbeat_ms == 250.0
    net.write_text(f'[nodes.2]\ndcf = "{dcf}"\n')
    assert load_network(str(net)).nodes[2][0].heartbeat_ms == 100.0


def test_missing_device_file_is_a_usage_error(tmp_path: Path) -> None:
    net = tmp_path / "net.toml"
    net.write_text('[nodes.2]\ndcf = "nope.dcf"\n')
    with pytest.raises(UsageError, match=r"nope\.dcf"):
        load_network(str(net))


def test_dcf_heartbeat_drives_h001_and_h003(checker, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """Node 2's DCF says 100 ms; it heartbeats every 300 ms: H003, and with the factor
    rule on the configured period every gap is an H001 timeout: an assumed limit (no
    consumer time is known), said once with the count (SPEC §7)."""
    dcf = shared_file("corpus/eds/lely/co-nmt-slave.dcf")
    frames = [(0.0, "702#00")] + [(0.3 * i, "702#7F") for i in range(1, 9)]
    net = f'[nodes.2]\ndcf = "{dcf}"\n'
    found = checker.findings(candump(frames), network=net, select="H003")
    assert found == [("H003", 2, 2.4)]
    assert checker.findings(candump(frames), select="H003") == []  # nothing configured
    h001 = checker.findings(candump(frames), network=net, select="H001")
    assert h001 == [("H001", 2, 0.45)]  # the boot-up starts no gap
    [f] = checker.run(candump(frames), network=net, select="H001").findings
    assert f.basis == "assumed" and "7 times in a row" in f.message


def test_compact_storage_as_lely_dcfgen_writes_it() -> None:
    """1016h and 1F81h as `CompactSubObj=127` + `[xxxxValue]` (canopen 2.4.1 ignores the
    Value sections): the consumer times and the slaves come from the INI text."""
    master = load_device_file(str(LELY_MASTER))
    assert master.notes == []
    assert master.node_id == 1  # [DeviceComissioning] NodeID
    assert master.consumers == {2: 300.0, 10: 150.0}  # 1=0x0002012C, 2=0x000A0096
    assert master.slaves == [2, 3, 10]  # sub-index 10 is decimal: node 10, not 16
    assert master.nmt_master  # 1F80h = 0x00000003
    assert master.heartbeat_ms == 500.0


def test_compact_storage_feeds_the_network(tmp_path: Path) -> None:
    net = tmp_path / "net.toml"
    net.write_text(f'[nodes.1]\ndcf = "{LELY_MASTER}"\n')
    network = load_network(str(net))
    assert [n for n, _ in network.expected()] == [1, 2, 3, 10]
    assert (network.nodes[2][0].consumer_timeout_ms, network.nodes[2][0].consumer_node) == (300, 1)
    assert network.nodes[10][0].consumer_timeout_ms == 150.0
    assert network.notes == []


def test_parameter_value_nodeid_and_unreadable_values() -> None:
    slave = load_device_file(str(SLAVE))
    assert slave.node_id == 5
    assert slave.heartbeat_ms == 250.0  # ParameterValue=250 over DefaultValue=0
    assert slave.guard_time_ms == 100.0  # empty ParameterValue: DefaultValue=0x64
    assert slave.life_time_factor == 8  # octal 010
    assert slave.tpdo_cob_ids == {1: 0x185, 2: 0x285, 3: None}  # 0x80000000+$NODEID+0x380
    assert slave.rpdo_cob_ids == {1: 0x205}
    assert not slave.nmt_master  # 1F80h = 0x08: self-starting slave, bit 0 clear
    assert slave.consumers == {1: 200.0}  # sub 2; sub 1 cannot be read ...
    assert slave.notes == ["1016h sub 1: cannot read ParameterValue=0x0001zz00 (not a number); "
                           "ignored"]  # ... and says so
    as_node_7 = load_device_file(str(SLAVE), 7)
    assert as_node_7.tpdo_cob_ids == {1: 0x187, 2: 0x287, 3: None}
    assert as_node_7.notes[0] == ("[DeviceComissioning] NodeID=5, but the file is used for "
                                  "node 7: $NODEID is 7")


def test_nodeid_unknown_and_invalid_node_id(tmp_path: Path) -> None:
    dcf = tmp_path / "x.dcf"
    dcf.write_text("[DeviceComissioning]\nNodeID=255\n"
                   "[1800]\nSubNumber=2\nParameterName=TPDO1\nObjectType=0x9\n"
                   "[1800sub0]\nParameterName=n\nDataType=0x0005\nAccessType=ro\nDefaultValue=1\n"
                   "[1800sub1]\nParameterName=COB-ID\nDataType=0x0007\nAccessType=rw\n"
                   "DefaultValue=$NODEID+0x180\n")
    values = load_device_file(str(dcf))
    assert values.node_id is None and values.tpdo_cob_ids == {}
    assert "[DeviceComissioning] NodeID=255 is not a node-ID 1..127; ignored" in values.notes
    assert ("1800h sub 1: cannot read DefaultValue=$NODEID+0x180 (uses $NODEID but the node-ID "
            "is not known); ignored") in values.notes


def test_compact_storage_oddities_are_notes(tmp_path: Path) -> None:
    """A `[1F81Name]` keyed by node-ID (canopen 2.4.1 raises on it), a hex key, a sub-index
    beyond CompactSubObj, a wrong NrOfEntries, a producer listed twice in 1016h: the readable
    entries count, the rest are notes. Entries not listed take the object's own DefaultValue
    (CiA 306)."""
    dcf = tmp_path / "m.dcf"
    dcf.write_text(
        "[DeviceComissioning]\nNodeID=1\n"
        "[1016]\nParameterName=Consumer heartbeat time\nObjectType=0x08\nDataType=0x0007\n"
        "AccessType=rw\nCompactSubObj=127\n"
        "[1016Value]\nNrOfEntries=2\n1=0x000200C8\n2=0x00020064\n"
        "[1F81]\nParameterName=NMT slave assignment\nObjectType=0x08\nDataType=0x0007\n"
        "AccessType=rw\nCompactSubObj=4\nDefaultValue=0x00000001\n"
        "[1F81Name]\nNrOfEntries=2\n2=Drive\n12=Sensor\n"
        "[1F81Value]\nNrOfEntries=2\n2=0x00000000\n0x03=0x00000005\n12=0x00000005\n"
        "[1F80]\nParameterName=NMT startup\nDataType=0x0007\nAccessType=rw\n"
        "DefaultValue=0x00000000\nParameterValue=0x00000001\n")
    values = load_device_file(str(dcf))
    assert values.consumers == {2: 100.0}
    assert values.slaves == [1, 3, 4]  # 2 is listed as 0; 1, 3 (hex key ignored), 4 by default
    assert values.nmt_master
    assert values.notes == [
        "1F81h [1F81Value]: NrOfEntries=2 but 3 entries",
        "1F81h [1F81Value] 0x03=0x00000005: '0x03' is not a decimal sub-index; ignored",
        "1F81h [1F81Value] 12=0x00000005: sub-index 12 outside 1..4 (CompactSubObj); ignored",
        "1016h sub 2: node 2 is also in sub 1; the shorter time is taken",
    ]


def test_array_sub_indices_are_not_made_up(tmp_path: Path) -> None:
    """canopen answers any missing sub-index of an array with a copy of sub 1; only the
    sub-indices the file has count."""
    dcf = tmp_path / "m.dcf"
    dcf.write_text(
        "[1F81]\nSubNumber=3\nParameterName=NMT slave assignment\nObjectType=0x8\n"
        "[1F81sub0]\nParameterName=n\nDataType=0x0005\nAccessType=ro\nDefaultValue=3\n"
        "[1F81sub1]\nParameterName=node 1\nDataType=0x0007\nAccessType=rw\nDefaultValue=0x5\n"
        "[1F81sub3]\nParameterName=node 3\nDataType=0x0007\nAccessType=rw\nDefaultValue=0x5\n")
    values = load_device_file(str(dcf), 9)
    assert values.slaves == [1, 3]


def test_nmt_startup_bit_0_in_real_files() -> None:
    gw = load_device_file(str(shared_file("corpus/eds/lely/co-gw_txt-master.dcf")))  # 0x00000001
    assert gw.nmt_master
    slave = shared_file("corpus/eds/lely/co-nmt-slave.dcf")
    assert not load_device_file(str(slave)).nmt_master  # 0x00000004


def test_samples_are_no_masters() -> None:
    for path in sorted(SAMPLES.glob("devices/*.dcf")):
        values = load_device_file(str(path))
        assert not values.nmt_master and values.notes == [], path.name
        assert values.node_id == int(path.stem.removeprefix("node"))


LELY_SAMPLE = SAMPLES / "lely" / "master.dcf"


@pytest.mark.skipif(not LELY_SAMPLE.is_file(), reason="samples/lely/master.dcf not recorded")
def test_lely_dcfgen_output() -> None:
    """The master DCF Lely's dcfgen wrote from samples/lely/master.yml (compact 1016h, 1F81h)."""
    master = load_device_file(str(LELY_SAMPLE))
    assert master.notes == []
    assert master.consumers == {2: 300.0, 3: 300.0}  # 3 x 100 ms
    assert master.slaves == [2, 3, 4]
    assert master.nmt_master and master.heartbeat_ms == 200.0
    network = load_network(None, {1: str(LELY_SAMPLE)})
    assert network.master_for("vcan0") == (1, "device-file",
                                           f"node 1 {LELY_SAMPLE}: 1F80h bit 0 set")
    assert network.nodes[2][0].consumer_timeout_ms == 300.0
