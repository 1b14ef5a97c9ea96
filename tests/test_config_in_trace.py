"""Configuration written by SDO in the trace (SPEC §6), EMCY and SDO-abort decoding."""

from __future__ import annotations

import pytest
from conftest import SAMPLES, candump

from nmtcheck.engine import check_input, select_rules
from nmtcheck.settings.profiles import load_profile


def hb(node: int, start: float, stop: float, period: float, state: str = "7F"
       ) -> list[tuple[float, str]]:
    out, t = [], start
    while t < stop - 1e-9:
        out.append((round(t, 6), f"{0x700 + node:03X}#{state}"))
        t += period
    return out


def write(node: int, t: float, index: int, sub: int, value: int, size: int = 2,
          answer: str = "60") -> list[tuple[float, str]]:
    cmd = {1: "2F", 2: "2B", 3: "27", 4: "23"}[size]
    body = f"{index & 0xFF:02X}{index >> 8:02X}{sub:02X}"
    val = value.to_bytes(4, "little").hex().upper()
    resp = (f"{0x580 + node:03X}#60{body}00000000" if answer == "60"
            else f"{0x580 + node:03X}#80{body}{answer}")
    return [(t, f"{0x600 + node:03X}#{cmd}{body}{val}"), (t + 0.001, resp)]


@pytest.mark.parametrize("suffix", [".log", ".asc"])
def test_ignored_1017_sample_gives_h003(suffix: str) -> None:
    profile = load_profile("default")
    res = check_input(str(SAMPLES / f"ignored_1017{suffix}"), 0, profile,
                      select_rules(profile, [], []))
    assert [(f.rule, f.node) for f in res.findings] == [("H003", 3)]
    assert "every 0.500 s" in res.findings[0].message and "0.100 s" in res.findings[0].message


def test_sdo_config_sample_is_clean_and_records_the_writes() -> None:
    profile = load_profile("default")
    res = check_input(str(SAMPLES / "sdo_config.log"), 0, profile, select_rules(profile, [], []))
    assert res.findings == []
    node2 = next(m for m in res.nodes() if m.node == 2)
    node3 = next(m for m in res.nodes() if m.node == 3)
    assert [(w.index, w.sub, w.value) for w in node2.writes] == [(0x1017, 0, 100),
                                                               (0x1016, 1, 0x000300FA)]
    assert node3.config_at(res.model.end).heartbeat_ms == 100.0
    cfg = node3.config_at(res.model.end)
    assert (cfg.consumer_timeout_ms, cfg.consumer_node) == (250.0, 2)
    assert [e.kind for e in node2.events] == ["sdo-write", "sdo-write"]


def test_written_producer_time_drives_h001_from_confirmation(checker) -> None:  # type: ignore[no-untyped-def]
    fr = [(0.0, "702#00")] + write(2, 0.05, 0x1017, 0, 200) + hb(2, 0.1, 1.0, 0.2)
    fr += hb(2, 1.6, 2.0, 0.2)  # a 0.7 s gap against 1.5 x 0.2 s = 0.3 s
    assert checker.findings(candump(sorted(fr)), select="H001,H003") == [("H001", 2, 1.2)]


def test_aborted_write_is_not_applied_and_decoded(checker) -> None:  # type: ignore[no-untyped-def]
    fr = [(0.0, "702#00")] + write(2, 0.05, 0x1017, 0, 500, answer="22000008")
    fr += hb(2, 0.1, 2.0, 0.1)
    res = checker.run(candump(sorted(fr)), select="H003")
    assert res.findings == []  # 500 ms was refused: no mismatch against it
    node = res.model.channels[0].nodes[2]
    assert len(node.writes) == 0
    (ev,) = node.events
    assert ev.kind == "sdo-abort" and ev.code == 0x08000022
    assert "1017h" in ev.text and "present device state" in ev.text


def test_heartbeat_disabled_by_sdo_is_no_timeout(checker) -> None:  # type: ignore[no-untyped-def]
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0, 0.1) + write(2, 1.0, 0x1017, 0, 0)
    fr += [(3.0, "182#01")]  # the trace goes on long after the last heartbeat
    assert checker.findings(candump(sorted(fr)), select="H001") == []


def test_written_value_reverts_at_bootup(checker) -> None:  # type: ignore[no-untyped-def]
    """After a boot-up the power-on value (here: none configured) applies again."""
    fr = [(0.0, "702#00")] + write(2, 0.05, 0x1017, 0, 100) + hb(2, 0.1, 1.0, 0.5)
    fr += [(1.2, "000#8102"), (1.3, "702#00")] + hb(2, 1.8, 5.0, 0.5)
    found = checker.findings(candump(sorted(fr)), select="H003")
    assert found == []  # only 1 interval under the written 100 ms, then nothing configured
    fr2 = [(0.0, "702#00")] + write(2, 0.05, 0x1017, 0, 100) + hb(2, 0.1, 3.5, 0.5)
    assert checker.findings(candump(sorted(fr2)), select="H003") == [("H003", 2, 3.1)]


def test_consumer_entry_written_by_sdo_names_the_consumer(checker) -> None:  # type: ignore[no-untyped-def]
    fr = [(0.0, "701#00"), (0.001, "703#00")]
    fr += write(1, 0.01, 0x1016, 1, 0x000300C8, size=4)  # node 1 consumes node 3, 200 ms
    fr += hb(3, 0.1, 1.0, 0.1) + hb(3, 1.5, 2.0, 0.1) + hb(1, 0.1, 2.0, 0.1)
    res = checker.run(candump(sorted(fr)), select="H001")
    (f,) = res.findings
    assert (f.node, round(f.time - 1000.0, 3)) == (3, 1.1)
    assert "consumer time 0.200 s of node 1" in f.message


def test_guard_time_written_by_sdo_drives_g003(checker) -> None:  # type: ignore[no-untyped-def]
    fr = [(0.0, "705#00")] + write(5, 0.01, 0x100C, 0, 100) + write(5, 0.02, 0x100D, 0, 3, 1)
    t, toggle = 0.1, 0
    for gap in [0.1] * 5 + [0.5] + [0.1] * 3:
        fr += [(round(t, 3), "705#R"), (round(t + 0.005, 3), f"705#{toggle << 7 | 0x7F:02X}")]
        toggle ^= 1
        t += gap
    assert checker.findings(candump(sorted(fr)), select="G003") == [("G003", 5, 1.1)]


def test_emcy_and_segmented_download_are_node_events(checker) -> None:  # type: ignore[no-untyped-def]
    fr = [(0.0, "701#00"), (0.5, "081#3081110000000000"), (0.6, "081#0000000000000000"),
          (0.7, "601#2117100002000000"), (0.701, "581#6017100000000000")]
    res = checker.run(candump(fr))
    events = list(res.model.channels[0].nodes[1].events)  # made one at a time
    assert [(e.kind, e.code) for e in events] == [("emcy", 0x8130), ("emcy", 0x0000),
                                                 ("sdo-segmented", None)]
    assert events[0].text.startswith("EMCY 8130h life guard error or heartbeat error")
    assert "error register 11h (generic, communication)" in events[0].text
    assert "not applied" in events[2].text


def test_pdo_moved_by_sdo_is_attributed_to_its_node(checker) -> None:  # type: ignore[no-untyped-def]
    """Node 2's TPDO1 moved to 1A2h (the default TPDO1 ID of node 34): frames on 1A2h while
    node 2 is pre-operational are its S001; frames on its old 182h are nobody's."""
    fr = [(0.0, "702#00")] + write(2, 0.05, 0x1800, 1, 0x1A2, size=4)
    fr += hb(2, 0.1, 2.0, 0.1)
    fr += [(0.5, "1A2#0102"), (0.6, "1A2#0102"), (0.7, "182#0102")]
    assert checker.findings(candump(sorted(fr)), select="S001") == [("S001", 2, 0.5)]
    res = checker.run(candump(sorted(fr)), select="S001")
    assert res.findings[0].message == "TPDO 1A2h sent while node 2 is PRE-OPERATIONAL (2 frames)"


def test_pdo_made_invalid_by_sdo_is_nobodys(checker) -> None:  # type: ignore[no-untyped-def]
    fr = [(0.0, "702#00")] + write(2, 0.05, 0x1800, 1, 0x80000182, size=4)
    fr += hb(2, 0.1, 2.0, 0.1) + [(0.5, "182#0102")]
    assert checker.findings(candump(sorted(fr)), select="S001") == []
    # without the write the same frame is node 2's PDO while pre-operational
    fr2 = [(0.0, "702#00")] + hb(2, 0.1, 2.0, 0.1) + [(0.5, "182#0102")]
    assert checker.findings(candump(sorted(fr2)), select="S001") == [("S001", 2, 0.5)]


def test_pdo_moved_outside_the_predefined_set_is_still_checked(checker) -> None:  # type: ignore[no-untyped-def]
    """A TPDO moved by SDO to 6A2h (no pre-defined ID) is still node 2's PDO."""
    fr = [(0.0, "702#00")] + write(2, 0.05, 0x1800, 1, 0x6A2, size=4)
    fr += hb(2, 0.1, 2.0, 0.1) + [(0.5, "6A2#0102"), (0.6, "6A2#0102"), (1.0, "000#0102")]
    fr += [(1.2, "6A2#0102")]  # operational now: fine
    assert checker.findings(candump(sorted(fr)), select="S001") == [("S001", 2, 0.5)]


def test_pdo_cob_id_from_the_network_dcf(checker, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The COB-ID comes from a DCF given in the network file (no SDO in the trace)."""
    dcf = tmp_path / "node2.dcf"
    dcf.write_text("[DeviceComissioning]\nNodeID=2\n[1800]\nSubNumber=2\nObjectType=0x9\n"
                   "[1800sub0]\nDataType=0x0005\nAccessType=ro\nDefaultValue=1\n"
                   "[1800sub1]\nDataType=0x0007\nAccessType=rw\nDefaultValue=0x6A2\n")
    fr = [(0.0, "702#00")] + hb(2, 0.1, 2.0, 0.1) + [(0.5, "6A2#0102"), (0.6, "182#0102")]
    net = f'[nodes.2]\ndcf = "{dcf}"\n'
    assert checker.findings(candump(sorted(fr)), select="S001", network=net) == [
        ("S001", 2, 0.5)]
    assert checker.findings(candump(sorted(fr)), select="S001") == [("S001", 2, 0.6)]


def test_healthy_sample_with_the_exported_dcfs() -> None:
    """samples/network.toml points at DCFs exported by canopen: values read, verdict clean."""
    from nmtcheck.settings.network import load_network

    net = load_network(str(SAMPLES / "network.toml"))
    assert {n: cfg.heartbeat_ms for n, (cfg, _c) in net.nodes.items()} == {
        2: 100.0, 3: 100.0, 4: 100.0}
    profile = load_profile("default")
    res = check_input(str(SAMPLES / "healthy.log"), 0, profile, select_rules(profile, [], []),
                      net)
    assert res.findings == []
    assert all(m.config.heartbeat_ms == 100.0 for m in res.nodes())
