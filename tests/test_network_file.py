"""The network file's `master` key (SPEC §6) and each channel's NMT master as the files name it
(SPEC §2): the network file, else 1F80h bit 0 in a node's device file."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from nmtcheck.errors import UsageError
from nmtcheck.settings.network import load_network

DEVICES = Path(__file__).resolve().parent / "data" / "devices"
MASTER_DCF = DEVICES / "lely_master.dcf"  # 1F80h = 0x00000003
SLAVE_DCF = DEVICES / "slave_values.dcf"  # 1F80h = 0x00000008


def _net(tmp_path: Path, text: str) -> str:
    """A network file beside copies of the test device files (paths relative to it)."""
    for dcf in (MASTER_DCF, SLAVE_DCF):
        shutil.copy(dcf, tmp_path / dcf.name)
    path = tmp_path / "net.toml"
    path.write_text(text)
    return str(path)


def test_top_level_master(tmp_path: Path) -> None:
    path = _net(tmp_path, "master = 1\n[nodes.3]\n")
    net = load_network(path)
    assert net.master_for("can0") == (1, "network", f"{path}: master = 1")
    assert net.master_for("1") == (1, "network", f"{path}: master = 1")


def test_channel_master_wins_over_top_level(tmp_path: Path) -> None:
    path = _net(tmp_path, "master = 1\n[channels.can1]\nmaster = 5\n[channels.can2]\n")
    net = load_network(path)
    assert net.master_for("can1") == (5, "network", f"{path}: [channels.can1] master = 5")
    assert net.master_for("can0")[:2] == (1, "network")  # type: ignore[index]
    assert net.master_for("can2")[:2] == (1, "network")  # type: ignore[index]


def test_channel_master_only(tmp_path: Path) -> None:
    net = load_network(_net(tmp_path, '[channels."vcan 0"]\nmaster = 127\n'))
    assert net.master_for("vcan 0")[:2] == (127, "network")  # type: ignore[index]
    assert net.master_for("can0") is None


def test_no_master(tmp_path: Path) -> None:
    net = load_network(_net(tmp_path, '[nodes.5]\ndcf = "slave_values.dcf"\n'))
    assert net.master_for("can0") is None  # 1F80h = 0x08: bit 0 clear


@pytest.mark.parametrize("value", ["0", "128", "-1", '"1"', "true", "1.0", "[1]"])
def test_invalid_master_is_a_usage_error(tmp_path: Path, value: str) -> None:
    path = _net(tmp_path, f"master = {value}\n")
    with pytest.raises(UsageError, match=rf"^{path}: master: expected a node-ID 1\.\.127"):
        load_network(path)
    path = _net(tmp_path, f"[channels.can0]\nmaster = {value}\n")
    with pytest.raises(UsageError,
                       match=rf"^{path}: \[channels\.can0\] master: expected a node-ID 1\.\.127"):
        load_network(path)


@pytest.mark.parametrize(("text", "message"), [
    ("[channels.can0]\nmastr = 1\n",
     r": \[channels\.can0\] mastr: unknown key \(known: master, boot, sync\)"),
    ("channels = 3\n", r": channels: expected \[channels\.NAME\] tables"),
    ("[channels]\ncan0 = 1\n", r": \[channels\.can0\]: expected a table"),
    ("masters = 1\n", r": unknown key 'masters'"),
])
def test_bad_channels_tables_are_usage_errors(tmp_path: Path, text: str, message: str) -> None:
    path = _net(tmp_path, text)
    with pytest.raises(UsageError, match=f"^{path}{message}"):
        load_network(path)


def test_master_from_a_device_file(tmp_path: Path) -> None:
    net = load_network(_net(tmp_path, '[nodes.1]\ndcf = "lely_master.dcf"\n'
                                      '[nodes.5]\ndcf = "slave_values.dcf"\n'))
    assert net.master_for("can0") == (
        1, "device-file", f"node 1 {tmp_path / 'lely_master.dcf'}: 1F80h bit 0 set")


def test_several_device_files_claim_it(tmp_path: Path) -> None:
    text = ('[nodes.9]\ndcf = "lely_master.dcf"\n[nodes.1]\ndcf = "lely_master.dcf"\n'
            '[nodes.5]\ndcf = "lely_master.dcf"\n[nodes.4]\ndcf = "slave_values.dcf"\n')
    net = load_network(_net(tmp_path, text))
    assert net.master_for("can0") == (
        1, "device-file", "nodes 1, 5 and 9 have 1F80h bit 0; lowest taken")
    net = load_network(_net(tmp_path, text.replace("[nodes.9]", "[nodes.9]\nchannel = 'can1'")))
    assert net.master_for("can0") == (
        1, "device-file", "nodes 1 and 5 have 1F80h bit 0; lowest taken")
    assert net.master_for("can1")[2] == (  # type: ignore[index]
        "nodes 1, 5 and 9 have 1F80h bit 0; lowest taken")


def test_a_device_file_counts_only_on_its_nodes_channel(tmp_path: Path) -> None:
    net = load_network(_net(tmp_path, '[nodes.1]\ndcf = "lely_master.dcf"\nchannel = "can1"\n'))
    assert net.master_for("can1")[:2] == (1, "device-file")  # type: ignore[index]
    assert net.master_for("can0") is None


def test_the_network_file_wins_over_device_files(tmp_path: Path) -> None:
    path = _net(tmp_path, 'master = 7\n[nodes.1]\ndcf = "lely_master.dcf"\n'
                          '[nodes.2]\ndcf = "lely_master.dcf"\n')
    assert load_network(path).master_for("can0") == (
        7, "network", f"{path}: master = 7 (nodes 1 and 2 also have 1F80h bit 0)")


def test_dcf_option_device_files_claim_it_on_every_channel(tmp_path: Path) -> None:
    net = load_network(None, {3: str(MASTER_DCF)})
    assert net.master_for("can0") == (3, "device-file", f"node 3 {MASTER_DCF}: 1F80h bit 0 set")
    assert net.nodes[3][0].expected


def test_notes_name_node_file_and_object(tmp_path: Path) -> None:
    """Notes are single lines naming the node, the device file and the object."""
    (tmp_path / "odd.dcf").write_text(
        "[DeviceComissioning]\nNodeID=4\n"
        "[1017]\nParameterName=Producer heartbeat time\nDataType=0x0006\nAccessType=rw\n"
        "DefaultValue=one hundred\n"
        "[100C]\nParameterName=Guard time\nDataType=0x0006\nAccessType=rw\n"
        "DefaultValue=0x10\n  0x20\n"  # a value continued on the next line
        "[1F81]\nParameterName=NMT slave assignment\nObjectType=0x08\nDataType=0x0007\n"
        "AccessType=rw\nCompactSubObj=127\n"
        "[1F81Value]\nNrOfEntries=1\n2=0x00000001\n300=0x00000001\n")
    path = _net(tmp_path, '[nodes.4]\ndcf = "odd.dcf"\n[nodes.5]\ndcf = "slave_values.dcf"\n'
                          '[nodes.6]\ndcf = "slave_values.dcf"\n')
    net = load_network(path)
    odd, slave = tmp_path / "odd.dcf", tmp_path / "slave_values.dcf"
    assert net.notes == [
        f"node 4 {odd}: 1F81h [1F81Value]: NrOfEntries=1 but 2 entries",
        f"node 4 {odd}: 1F81h [1F81Value] 300=0x00000001: sub-index 300 outside 1..127 "
        f"(CompactSubObj); ignored",
        f"node 4 {odd}: 1017h: cannot read DefaultValue=one hundred (not a number); ignored",
        f"node 4 {odd}: 100Ch: cannot read DefaultValue=0x10 0x20 (not a number); ignored",
        f"node 5 {slave}: 1016h sub 1: cannot read ParameterValue=0x0001zz00 (not a number); "
        f"ignored",
        f"node 6 {slave}: [DeviceComissioning] NodeID=5, but the file is used for node 6: "
        f"$NODEID is 6",
        f"node 6 {slave}: 1016h sub 1: cannot read ParameterValue=0x0001zz00 (not a number); "
        f"ignored",
    ]
    assert all("\n" not in note for note in net.notes)
    assert [n for n, _ in net.expected()] == [2, 4, 5, 6]
