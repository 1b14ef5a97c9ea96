"""EDS/DCF reading on the real files of the corpus, and what the network file takes from them."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import CORPUS, candump

from nmtcheck.devicefile import load_device_file
from nmtcheck.errors import UsageError
from nmtcheck.network import load_network

EDS = CORPUS / "eds"
ALL_FILES = sorted([*EDS.glob("*/*.eds"), *EDS.glob("*/*.dcf")])


@pytest.mark.parametrize("path", ALL_FILES, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_corpus_file_loads(path: Path) -> None:
    values = load_device_file(str(path), 5)
    assert values.path == str(path)
    assert values.reader in ("canopen", "ini")


@pytest.mark.parametrize("name", ["canopennode/DS301_profile.eds", "lely/co-gw_txt-master.dcf"])
def test_files_canopen_rejects_are_read_anyway_with_a_note(name: str) -> None:
    values = load_device_file(str(EDS / name), 5)
    assert values.reader == "ini"
    assert values.notes and "canopen could not import it" in values.notes[0]


def test_values_from_real_files() -> None:
    lely = load_device_file(str(EDS / "lely/co-nmt-slave.dcf"))
    assert (lely.node_id, lely.heartbeat_ms) == (2, 100.0)  # ParameterValue=100 wins over 0
    oresat = load_device_file(str(EDS / "oresat/battery.dcf"), 5)
    assert oresat.heartbeat_ms == 1000.0
    assert oresat.tpdo_cob_ids == {1: 0x185, 2: 0x285, 3: 0x385, 4: 0x485}
    e35 = load_device_file(str(EDS / "python-canopen/e35.eds"), 5)
    assert (e35.guard_time_ms, e35.life_time_factor) == (100.0, 4)
    # a COB-ID with bit 31 set: the PDO is not valid
    assert e35.rpdo_cob_ids[2] is None
    pdo = load_device_file(str(EDS / "lely/co-pdo-transmit.dcf"), 7)
    assert pdo.tpdo_cob_ids == {1: 0x187}  # $NODEID+0x180 resolved with the given node-ID


def test_canopen_and_ini_readers_agree(tmp_path: Path) -> None:
    """The fallback gives the same values as canopen where canopen can read the file."""
    from nmtcheck import devicefile

    for path in [EDS / "oresat/imu.dcf", EDS / "python-canopen/sample.eds",
                 EDS / "lely/co-nmt-slave.dcf"]:
        via_canopen = load_device_file(str(path), 9)
        original = devicefile._CanopenOD
        devicefile._CanopenOD = None  # type: ignore[assignment,misc]  # force the fallback
        try:
            via_ini = load_device_file(str(path), 9)
        finally:
            devicefile._CanopenOD = original  # type: ignore[misc]
        assert via_ini.reader == "ini"
        for key in ("heartbeat_ms", "consumers", "guard_time_ms", "life_time_factor",
                    "tpdo_cob_ids", "rpdo_cob_ids", "slaves"):
            assert getattr(via_ini, key) == getattr(via_canopen, key), (path.name, key)


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
    dcf = EDS / "lely/co-nmt-slave.dcf"
    net.write_text(f'[nodes.2]\ndcf = "{dcf}"\nheartbeat_ms = 250\n')
    assert load_network(str(net)).nodes[2][0].heartbeat_ms == 250.0
    net.write_text(f'[nodes.2]\ndcf = "{dcf}"\n')
    assert load_network(str(net)).nodes[2][0].heartbeat_ms == 100.0


def test_missing_device_file_is_a_usage_error(tmp_path: Path) -> None:
    net = tmp_path / "net.toml"
    net.write_text('[nodes.2]\ndcf = "nope.dcf"\n')
    with pytest.raises(UsageError, match="nope.dcf"):
        load_network(str(net))


def test_dcf_heartbeat_drives_h001_and_h003(checker, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """Node 2's DCF says 100 ms; it heartbeats every 300 ms: H003, and with the factor
    rule on the configured period every gap is an H001 timeout."""
    dcf = EDS / "lely/co-nmt-slave.dcf"
    frames = [(0.0, "702#00")] + [(0.3 * i, "702#7F") for i in range(1, 9)]
    net = f'[nodes.2]\ndcf = "{dcf}"\n'
    found = checker.findings(candump(frames), network=net, select="H003")
    assert found == [("H003", 2, 2.4)]
    assert checker.findings(candump(frames), select="H003") == []  # nothing configured
    h001 = checker.findings(candump(frames), network=net, select="H001")
    assert h001[0] == ("H001", 2, 0.15) and len(h001) == 8
