"""Boot-process rules P001-P008 (SPEC §8.4): the test vectors of SPEC_BOOT §8.7 verbatim."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from conftest import Checker

from nmtcheck.results import InputResult

BOOT_TOML = "master = 1\n[boot]\nmanager = true\n[nodes.2]\n"
M1_TOML = "master = 1\n"


def run(checker: Checker, log: str, network: str) -> InputResult:
    return checker.run(log.strip() + "\n", network=network)


def p_findings(res: InputResult) -> list[tuple[str, int | None, float, int | None, int | None]]:
    return [(f.rule, f.node, round(f.time, 6), f.frame_index, f.line) for f in res.findings
            if f.rule.startswith("P")]


def boot_of(res: InputResult, node: int, channel: str = "can0") -> Any:
    assert res.boot is not None
    return res.boot.nodes[(channel, node)]


# --- P001 ------------------------------------------------------------------------------

P001_NET = BOOT_TOML + "vendor_id = 0x00000300\nproduct_code = 0x00004645\n"
P001_LOG = """
(10.000000) can0 701#00
(10.010000) can0 000#8200
(10.020000) can0 702#00
(10.021000) can0 602#4000100000000000
(10.022000) can0 582#4300100092010200
(10.023000) can0 602#4018100100000000
(10.024000) can0 582#4318100100030000
(10.025000) can0 602#4018100200000000
(10.026000) can0 582#4318100244460000
(11.000000) can0 080#
"""


def test_p001_fires(checker: Checker) -> None:
    res = run(checker, P001_LOG, P001_NET)
    assert p_findings(res) == [("P001", 2, 10.026, 8, 9)]
    f = next(f for f in res.findings if f.rule == "P001")
    assert f.boot_letter == "M"
    assert f.evidence == {"time": 10.026, "frame_index": 8, "line": 9}
    assert "0x00004644" in f.message and "0x00004645" in f.message
    rep = boot_of(res, 2)
    assert (rep.status, rep.letter, rep.letter_source) == ("failed", "M", "observed")
    assert rep.reason == ("Value of object 1018 sub-index 02 from CANopen device is different "
                          "to value in object 1F86 (Product code).")


def test_p001_silent(checker: Checker) -> None:
    log = P001_LOG.replace("(11.000000) can0 080#", "(10.027000) can0 000#0102\n"
                           "(11.000000) can0 080#")
    res = run(checker, log, P001_NET.replace("0x00004645", "0x00004644"))
    assert p_findings(res) == []
    assert boot_of(res, 2).status == "ok"


# --- P002 ------------------------------------------------------------------------------

P002_LOG = """
(10.000000) can0 701#00
(10.010000) can0 000#8200
(10.020000) can0 702#00
(10.021000) can0 602#4000100000000000
(10.121000) can0 602#8000100000000405
(10.122000) can0 602#4000100000000000
(10.222000) can0 602#8000100000000405
(10.223000) can0 602#4000100000000000
(10.323000) can0 602#8000100000000405
(10.324000) can0 602#4000100000000000
(10.424000) can0 602#8000100000000405
(11.424000) can0 602#4000100000000000
(11.524000) can0 602#8000100000000405
(12.000000) can0 080#
(14.000000) can0 080#
"""

P002_SILENT = """
(10.000000) can0 701#00
(10.010000) can0 000#8200
(10.011000) can0 602#4000100000000000
(10.111000) can0 602#8000100000000405
(10.112000) can0 602#4000100000000000
(10.113000) can0 702#00
(10.150000) can0 582#4300100092010200
(10.151000) can0 000#0102
"""


def test_p002_fires(checker: Checker) -> None:
    res = run(checker, P002_LOG, BOOT_TOML)
    assert p_findings(res) == [("P002", 2, 11.524, 12, 13)]
    assert next(f for f in res.findings if f.rule == "P002").boot_letter == "B"


def test_p002_silent_probes_before_bootup(checker: Checker) -> None:
    res = run(checker, P002_SILENT, BOOT_TOML)
    assert p_findings(res) == []
    rep = boot_of(res, 2)
    assert rep.status == "ok"
    x = rep.process
    assert x.attempts == 1
    steps = [(s.step, round(s.time, 6), s.result, None if s.end is None else round(s.end.time, 6))
             for s in x.steps]
    assert steps == [("reset", 10.01, None, None),
                     ("device_type", 10.011, "timeout", 10.111),
                     ("device_type", 10.112, "ok", 10.15),
                     ("bootup", 10.113, None, None),
                     ("start", 10.151, None, None)]


# --- P003 ------------------------------------------------------------------------------

P003_LOG = """
(10.000000) can0 701#00
(10.010000) can0 000#8200
(10.020000) can0 702#00
(10.021000) can0 602#4000100000000000
(10.022000) can0 582#4300100092010200
(10.023000) can0 602#2F60600001000000
(10.024000) can0 582#6060600000000000
(10.025000) can0 602#2300140102020080
(10.026000) can0 582#8000140111000906
(11.000000) can0 080#
"""

P003_SILENT = """
(10.000000) can0 701#00
(10.010000) can0 000#8200
(10.020000) can0 702#00
(10.021000) can0 602#4000100000000000
(10.022000) can0 582#4300100092010200
(10.023000) can0 602#2F60600001000000
(10.024000) can0 582#6060600000000000
(10.025000) can0 000#0102
(10.500000) can0 602#2300140102020080
(10.501000) can0 582#8000140111000906
"""


def test_p003_fires(checker: Checker) -> None:
    res = run(checker, P003_LOG, BOOT_TOML)
    assert p_findings(res) == [("P003", 2, 10.026, 8, 9)]
    f = next(f for f in res.findings if f.rule == "P003")
    assert f.boot_letter == "J"
    assert "06090011h" in f.message and "sub-index does not exist" in f.message
    assert "1400h:01" in f.message


def test_p003_silent_after_start(checker: Checker) -> None:
    res = run(checker, P003_SILENT, BOOT_TOML)
    assert p_findings(res) == []
    assert boot_of(res, 2).status == "ok"


# --- P004 ------------------------------------------------------------------------------

P004_NET = BOOT_TOML + "manager_consumer_ms = 300\n"
P004_HEAD = """
(10.000000) can0 701#00
(10.010000) can0 000#8200
(10.020000) can0 702#00
(10.021000) can0 602#4000100000000000
(10.022000) can0 582#4300100092010200
(10.023000) can0 602#2F60600001000000
(10.024000) can0 582#6060600000000000
"""


def test_p004_fires(checker: Checker) -> None:
    res = run(checker, P004_HEAD + "(11.000000) can0 080#\n", P004_NET)
    assert p_findings(res) == [("P004", 2, 10.324, 7, 8)]
    f = next(f for f in res.findings if f.rule == "P004")
    assert f.boot_letter == "K"
    assert f.evidence is not None and f.evidence["frame_index"] == 6


def test_p004_silent(checker: Checker) -> None:
    log = P004_HEAD + ("(10.124000) can0 702#7F\n(10.125000) can0 000#0102\n"
                       "(10.200000) can0 080#\n")
    res = run(checker, log, P004_NET)
    assert p_findings(res) == []
    assert boot_of(res, 2).status == "ok"


# --- P005 ------------------------------------------------------------------------------

P005_LOG = """
(10.000000) can0 702#05
(10.100000) can0 702#05
(10.150000) can0 701#00
(10.151000) can0 602#4000100000000000
(10.152000) can0 582#4300100092010200
(10.200000) can0 702#05
(10.300000) can0 702#05
"""

P005_SILENT = """
(10.000000) can0 702#05
(10.150000) can0 701#00
(10.160000) can0 000#8202
(10.161000) can0 602#4000100000000000
(10.162000) can0 702#05
(10.170000) can0 702#00
(10.261000) can0 602#8000100000000405
(10.262000) can0 602#4000100000000000
(10.263000) can0 582#4300100092010200
(10.264000) can0 000#0102
(10.364000) can0 702#05
"""


def test_p005_fires(checker: Checker) -> None:
    res = run(checker, P005_LOG, BOOT_TOML)
    assert p_findings(res) == [("P005", 2, 10.2, 5, 6)]
    assert next(f for f in res.findings if f.rule == "P005").boot_letter == "L"
    rep = boot_of(res, 2)
    assert (rep.status, rep.letter) == ("ok", "L")
    assert rep.process.keep_alive


def test_p005_silent_stale_report(checker: Checker) -> None:
    res = run(checker, P005_SILENT, BOOT_TOML)
    assert p_findings(res) == []
    assert [f.rule for f in res.findings if f.rule == "B001"] == []
    assert boot_of(res, 2).status == "ok"


# --- P006 ------------------------------------------------------------------------------

P006_NET = ("master = 1\n[boot]\nmanager = true\nboot_time_ms = 2000\n[nodes.2]\n"
            "mandatory = true\n")
P006_LOG = """
(10.000000) can0 701#00
(10.010000) can0 000#8200
(10.020000) can0 702#00
(10.021000) can0 602#4000100000000000
(10.022000) can0 582#4300100092010200
(10.023000) can0 602#4018100100000000
(10.024000) can0 582#4318100100030000
(11.000000) can0 080#
(12.000000) can0 080#
(13.000000) can0 080#
"""


def test_p006_fires(checker: Checker) -> None:
    res = run(checker, P006_LOG, P006_NET)
    assert p_findings(res) == [("P006", 2, 12.0, 8, 9)]
    assert next(f for f in res.findings if f.rule == "P006").boot_letter is None


def test_p006_silent(checker: Checker) -> None:
    log = P006_LOG.replace("(11.000000)", "(10.025000) can0 000#0102\n(11.000000)")
    res = run(checker, log, P006_NET)
    assert p_findings(res) == []


# --- P007 ------------------------------------------------------------------------------

P007_LOG = """
(10.000000) can0 701#00
(10.010000) can0 000#8200
(10.020000) can0 702#00
(10.021000) can0 602#4000100000000000
(10.022000) can0 582#4300100092010200
(10.023000) can0 602#2F60600001000000
(10.023500) can0 000#0100
(10.024000) can0 582#6060600000000000
(10.100000) can0 080#
"""

P007_SILENT = """
(10.000000) can0 701#00
(10.010000) can0 000#8200
(10.020000) can0 702#00
(10.021000) can0 602#4000100000000000
(10.022000) can0 582#4300100092010200
(10.023000) can0 602#2F60600001000000
(10.023500) can0 582#6060600000000000
(10.024000) can0 000#0100
(10.100000) can0 080#
"""


def test_p007_fires(checker: Checker) -> None:
    res = run(checker, P007_LOG, BOOT_TOML)
    assert p_findings(res) == [("P007", 2, 10.0235, 6, 7)]
    assert boot_of(res, 2).status == "failed"


def test_p007_silent(checker: Checker) -> None:
    res = run(checker, P007_SILENT, BOOT_TOML)
    assert p_findings(res) == []
    rep = boot_of(res, 2)
    assert rep.status == "ok"
    assert round(rep.process.started_at.time, 6) == 10.024


# --- P008 ------------------------------------------------------------------------------

P008_LOG = """
(10.000000) can0 701#00
(10.010000) can0 000#8200
(10.020000) can0 702#00
(10.020500) can0 703#00
(10.021000) can0 602#4000100000000000
(10.022000) can0 582#4300100092010200
(10.023000) can0 602#4018100100000000
(10.024000) can0 582#4318100100030000
(10.025000) can0 602#4018100200000000
(10.026000) can0 582#4318100244460000
(10.027000) can0 603#4000100000000000
(10.028000) can0 583#4300100092010200
(10.029000) can0 000#0103
(15.000000) can0 080#
(21.000000) can0 080#
"""

P008_SILENT = """
(10.000000) can0 701#00
(10.010000) can0 000#8200
(10.020000) can0 702#00
(10.021000) can0 602#4000100000000000
(10.022000) can0 582#4300100092010200
(10.023000) can0 602#4018100100000000
(10.024000) can0 582#4318100100030000
(15.000000) can0 702#00
(15.001000) can0 602#4000100000000000
(15.002000) can0 582#4300100092010200
(15.003000) can0 000#0102
(26.000000) can0 080#
"""


def test_p008_fires(checker: Checker) -> None:
    res = run(checker, P008_LOG, M1_TOML)
    assert p_findings(res) == [("P008", 2, 10.02 + 10.0, 14, 15)]
    f = next(f for f in res.findings if f.rule == "P008")
    assert ("stopped after product_code 1018:02 = 0x00004644 (line 10); candidates M, K, "
            "no start") in f.message
    assert res.boot is not None and res.boot.channels["can0"].manager == "inferred"
    assert boot_of(res, 3).status == "ok"


def test_p008_silent_slave_boots_twice(checker: Checker) -> None:
    res = run(checker, P008_SILENT, BOOT_TOML)
    assert p_findings(res) == []
    assert ("B002", 2, 15.0) in [(f.rule, f.node, round(f.time, 6)) for f in res.findings]
    assert boot_of(res, 2).status == "ok"
    assert boot_of(res, 2).processes == 2


# --- group decision --------------------------------------------------------------------

NOT_A_MANAGER = """
(10.000000) can0 701#00
(10.010000) can0 000#8200
(10.020000) can0 702#00
(10.030000) can0 000#0100
(10.031000) can0 602#4041600000000000
(10.032000) can0 582#4B41600037020000
(21.000000) can0 080#
"""


def test_group_off_without_signature(checker: Checker) -> None:
    res = run(checker, NOT_A_MANAGER, M1_TOML)
    assert p_findings(res) == []
    assert res.boot is not None and res.boot.channels["can0"].manager == "none"
    assert boot_of(res, 2).status == "not-managed"


def test_one_probe_is_no_signature(checker: Checker) -> None:
    log = NOT_A_MANAGER.replace("4041600000000000", "4000100000000000").replace(
        "4B41600037020000", "4300100092010200").replace("(10.030000) can0 000#0100\n", "")
    res = run(checker, log, M1_TOML)
    assert res.boot is not None and res.boot.channels["can0"].manager == "none"


def test_manager_false_turns_the_group_off(checker: Checker) -> None:
    res = run(checker, P001_LOG, P001_NET.replace("manager = true", "manager = false"))
    assert p_findings(res) == []
    assert res.boot is not None and res.boot.channels["can0"].manager == "off"


@pytest.mark.parametrize("code", [f"P00{i}" for i in range(1, 9)])
def test_rule_docs(code: str) -> None:
    from nmtcheck.checks import BY_CODE

    doc = BY_CODE[code].doc
    for part in ("**What it checks.**", "**Why it matters.**", "**Example.**"):
        assert part in doc


def test_tmp_path_unused(tmp_path: Path) -> None:
    assert tmp_path.exists()


# --- causes (SPEC §8.6, vectors C1 and C2) ---------------------------------------------

C1_LOG = """
(10.000000) can0 705#05
(10.100000) can0 705#05
(10.200000) can0 705#05
(10.300000) can0 705#05
(11.000000) can0 085#4081110000000000
(11.010000) can0 705#05
"""

C2_LOG = """
(10.000000) can0 702#05
(10.000500) can0 703#05
(10.001000) can0 704#05
(11.000000) can0 702#05
(11.000500) can0 703#05
(11.001000) can0 704#05
(11.500000) can0 702#00
(11.520000) can0 703#00
(11.540000) can0 704#00
"""


def test_c1_emcy_after_the_timeout(checker: Checker) -> None:
    """SPEC §9.3.7: the EMCY after the timeout reports it; it cannot have caused it."""
    res = checker.run(C1_LOG.strip() + "\n")
    h = [f for f in res.findings if f.rule == "H001"]
    assert [(f.node, round(f.time, 6), f.frame_index) for f in h] == [(5, 10.45, 4)]
    assert h[0].causes == [] and h[0].causes_omitted == 0
    reactions = [{k: c[k] for k in ("kind", "node", "code", "time", "frame_index", "line",
                                    "role")} for c in h[0].reactions or []]
    assert reactions == [{"kind": "emcy", "node": 5, "code": "8140h", "time": 11.0,
                          "frame_index": 4, "line": 5, "role": "report"}]
    assert h[0].reactions_omitted == 0


def test_c2_bootup_cluster(checker: Checker) -> None:
    res = checker.run(C2_LOG.strip() + "\n")
    b = [f for f in res.findings if f.rule == "B002"]
    got = []
    for f in b:
        cl = [c for c in f.causes or [] if c["kind"] == "bootup_cluster"]
        assert len(cl) == 1 and cl[0]["node"] is None
        got.append((f.node, round(f.time, 6), cl[0]["text"].split(" within")[0], cl[0]["time"],
                    cl[0]["end"]))
    # SPEC §9.3.7: the earliest and the latest boot-up among N and the nodes it lists, so
    # that the cluster begins at or before N's own boot-up (a common cause before them)
    assert got == [(2, 11.5, "boot-ups of node(s) 3, 4", 11.5, 11.54),
                   (3, 11.52, "boot-ups of node(s) 2, 4", 11.5, 11.54),
                   (4, 11.54, "boot-ups of node(s) 2, 3", 11.5, 11.54)]


def test_only_cause_rules_carry_causes(checker: Checker) -> None:
    res = run(checker, P001_LOG, P001_NET)
    assert all(f.causes is None for f in res.findings if f.rule not in
               ("H001", "G002", "B001", "B002", "S004"))
