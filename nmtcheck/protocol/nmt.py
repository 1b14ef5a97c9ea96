"""The NMT vocabulary of CiA 301: states, state codes, command specifiers, kinds of
error-control frame, and the few comparisons every stage makes on them."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

UNKNOWN = "UNKNOWN"
INITIALISING = "INITIALISING"
PRE_OPERATIONAL = "PRE-OPERATIONAL"
OPERATIONAL = "OPERATIONAL"
STOPPED = "STOPPED"
OFFLINE = "OFFLINE"
STATES = (UNKNOWN, INITIALISING, PRE_OPERATIONAL, OPERATIONAL, STOPPED, OFFLINE)
STATE_INDEX = {s: i for i, s in enumerate(STATES)}

STATE_OF_CODE = {0x00: PRE_OPERATIONAL, 0x04: STOPPED, 0x05: OPERATIONAL, 0x7F: PRE_OPERATIONAL}
CODE_NAMES = {0x00: "boot-up", 0x04: "STOPPED", 0x05: "OPERATIONAL", 0x7F: "PRE-OPERATIONAL"}

CS_START, CS_STOP, CS_PREOP, CS_RESET_NODE, CS_RESET_COMM = 0x01, 0x02, 0x80, 0x81, 0x82
COMMAND_STATE = {CS_START: OPERATIONAL, CS_STOP: STOPPED, CS_PREOP: PRE_OPERATIONAL,
                 CS_RESET_NODE: INITIALISING, CS_RESET_COMM: INITIALISING}
COMMAND_NAMES = {CS_START: "start", CS_STOP: "stop", CS_PREOP: "enter pre-operational",
                 CS_RESET_NODE: "reset node", CS_RESET_COMM: "reset communication"}
RESETS = (CS_RESET_NODE, CS_RESET_COMM)
EPS = 1e-7  # timestamps are microseconds at best: ignore float noise in comparisons


def state_name(code: int) -> str:
    return CODE_NAMES.get(code, f"{code:02X}h")


REQUEST, BOOTUP, HEARTBEAT, GUARD, MALFORMED = range(5)
EC_KIND_NAMES = ("request", "bootup", "heartbeat", "guard", "malformed")  # by EcTable.kind

SOURCES = ("start", "command", "timeout", "bootup", "heartbeat", "guarding", "self-start")
SOURCE_INDEX = {s: i for i, s in enumerate(SOURCES)}


def between(sorted_marks: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Per pair, whether a mark m with lo < m < hi exists."""
    if not len(sorted_marks):
        return np.zeros(len(lo), bool)
    return (np.searchsorted(sorted_marks, lo, side="right")
            < np.searchsorted(sorted_marks, hi, side="left"))


def is_one_of(values: np.ndarray, choices: Iterable[int] | np.ndarray) -> np.ndarray:
    """`np.isin` for a few choices or few values: one comparison per choice (np.isin
    costs tens of microseconds a call, and the per-node checks call it for every node
    of a log that may have tens of thousands)."""
    choices = np.asarray(choices).ravel()
    if len(choices) > 8:
        return np.isin(values, choices)
    hit = np.zeros(np.shape(values), bool)
    for c in choices.tolist():
        hit |= values == c
    return hit


def nmt_problem(rtr: bool, dlc: int, cs: int, target: int) -> str | None:
    """Why a frame on CAN-ID 000h is not a valid command (C002), None if it is."""
    if rtr:
        return "remote frame on CAN-ID 000h (NMT commands are data frames)"
    if dlc != 2:
        return f"DLC {dlc} (an NMT command has DLC 2)"
    if cs not in COMMAND_STATE:
        return f"unknown command specifier {cs:02X}h"
    if target > 127:
        return f"node-ID {target} above 127"
    return None
