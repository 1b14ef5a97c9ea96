"""P004 (b) after the keep-alive state check resets the slave, and P003 (b) after the
restore of defaults (SPEC_BOOT §8.4): each fires, and stays silent when the slave answers.

The keep-alive vectors follow what Lely's manager did in samples/lely/keepalive/ (node 2
heartbeats 7Fh, the manager sends 000#8202, the boot-up follows): there the heartbeat
after the boot-up ended the wait and the manager configured and started the node."""

from __future__ import annotations

from conftest import Checker
from test_rules_boot import boot_of, p_findings, run

# node 2 is a keep-alive slave (1F81h bit 4) whose heartbeat the manager consumes
KA_NET = ("master = 1\n[boot]\nmanager = true\n[nodes.2]\nreset_communication = false\n"
          "manager_consumer_ms = 300\n")
# the same, guarded: no consumer entry for node 2, so the state check is an RTR
KA_GUARDED_NET = "master = 1\n[boot]\nmanager = true\n[nodes.2]\nreset_communication = false\n"

KA_HEAD = """
(10.000000) can0 701#00
(10.001000) can0 000#8203
(10.002000) can0 602#4000100000000000
(10.003000) can0 582#4300100092010200
"""

KA_RESET = KA_HEAD + """(10.100000) can0 702#7F
(10.100100) can0 000#8202
(10.100200) can0 702#00
"""


def test_p004_keep_alive_reset_without_answer(checker: Checker) -> None:
    """The state check saw 7Fh and reset node 2; its boot-up came, then nothing: Lely's
    wait for the answer runs out after 1000 ms (E)."""
    res = run(checker, KA_RESET + "(11.500000) can0 080#\n", KA_NET)
    assert p_findings(res) == [("P004", 2, 11.1001, 7, 8)]
    f = next(f for f in res.findings if f.rule == "P004")
    assert f.boot_letter == "E"
    assert f.evidence == {"time": 10.1001, "frame_index": 5, "line": 6}
    assert "boot-up came" in f.message
    rep = boot_of(res, 2)
    assert rep.process is not None and rep.process.keep_alive
    assert (rep.status, rep.letter) == ("failed", "E")


def test_p004_keep_alive_reset_answered(checker: Checker) -> None:
    """A heartbeat after the reset ends the wait; the manager configures and starts."""
    log = KA_RESET + """(10.200000) can0 702#7F
(10.200100) can0 602#2B17100064000000
(10.200200) can0 582#6017100000000000
(10.300000) can0 702#7F
(10.300100) can0 000#0102
(11.500000) can0 080#
"""
    res = run(checker, log, KA_NET)
    assert p_findings(res) == []
    assert boot_of(res, 2).status == "ok"


def test_p004_keep_alive_reset_trace_ends_first(checker: Checker) -> None:
    res = run(checker, KA_RESET + "(10.900000) can0 080#\n", KA_NET)
    assert p_findings(res) == []
    assert boot_of(res, 2).status == "incomplete"


def test_p004_keep_alive_reset_guarded_is_f(checker: Checker) -> None:
    """Without a consumer entry the state check is an RTR; the answer 7Fh leads to the
    reset, and the unanswered wait after it is F."""
    log = KA_HEAD + """(10.003100) can0 702#R
(10.004000) can0 702#7F
(10.004100) can0 000#8202
(10.004200) can0 702#00
(11.500000) can0 080#
"""
    res = run(checker, log, KA_GUARDED_NET)
    assert p_findings(res) == [("P004", 2, 11.0041, 8, 9)]
    assert next(f for f in res.findings if f.rule == "P004").boot_letter == "F"


def test_p004_not_keep_alive_reset_is_no_state_check(checker: Checker) -> None:
    """The same frames with a slave that is not keep-alive: the 7Fh is its error-control
    heartbeat, the reset is the manager's own business: no P004 (b)."""
    net = KA_NET.replace("reset_communication = false\n", "")
    res = run(checker, KA_RESET + "(11.500000) can0 080#\n", net)
    assert p_findings(res) == []
    rep = boot_of(res, 2)
    assert rep.process is not None and not rep.process.keep_alive
    assert rep.status == "incomplete"


# --- P003 (b) ----------------------------------------------------------------------------

RESTORE = """
(10.000000) can0 701#00
(10.010000) can0 000#8200
(10.020000) can0 702#00
(10.021000) can0 602#4000100000000000
(10.022000) can0 582#4300100092010200
(10.023000) can0 602#231110046C6F6164
(10.024000) can0 582#6011100400000000
(10.025000) can0 000#8202
"""
BOOT_TOML = "master = 1\n[boot]\nmanager = true\n[nodes.2]\n"


def test_p003_restore_without_bootup_fires(checker: Checker) -> None:
    res = run(checker, RESTORE + "(11.500000) can0 080#\n", BOOT_TOML)
    assert p_findings(res) == [("P003", 2, 10.025, 7, 8)]
    f = next(f for f in res.findings if f.rule == "P003")
    assert f.boot_letter == "J"
    assert "1011h:04" in f.message and "line 8" in f.message


def test_p003_restore_with_bootup_silent(checker: Checker) -> None:
    log = RESTORE + """(10.026000) can0 702#00
(10.027000) can0 602#4000100000000000
(10.028000) can0 582#4300100092010200
(10.029000) can0 000#0102
(11.500000) can0 080#
"""
    res = run(checker, log, BOOT_TOML)
    assert p_findings(res) == []
    rep = boot_of(res, 2)
    assert rep.status == "ok" and rep.process is not None and rep.process.attempts == 2


def test_p003_restore_trace_ends_first(checker: Checker) -> None:
    res = run(checker, RESTORE + "(10.900000) can0 080#\n", BOOT_TOML)
    assert p_findings(res) == []
