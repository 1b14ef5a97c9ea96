"""Write the slave EDS variants of the SYNC/PDO/EMCY recordings from ../slave.eds (run here).

Each variant adds a few objects to slave.eds (SYNC 1005h/1006h, an RPDO, a TPDO type);
the table in README.md says which and why. Kept as a script so the difference is
reviewable."""

import re
from pathlib import Path

BASE = Path(__file__).resolve().parent.parent / "slave.eds"


def var(index: str, name: str, datatype: str, value: str, access: str = "rw",
        pdo: int = 0) -> list[str]:
    return [f"[{index}]", f"ParameterName={name}", f"DataType={datatype}",
            f"AccessType={access}", f"DefaultValue={value}", f"PDOMapping={pdo}", ""]


def record(index: str, name: str, subs: list[tuple[str, str, str]]) -> list[str]:
    """subs: (name, datatype, value) of sub 1..n; sub 0 = n."""
    out = [f"[{index}]", f"SubNumber={len(subs) + 1}", f"ParameterName={name}",
           "ObjectType=0x09", ""]
    out += var(f"{index}sub0", "Highest sub-index supported", "0x0005", str(len(subs)), "const")
    for k, (sub_name, datatype, value) in enumerate(subs, 1):
        out += var(f"{index}sub{k}", sub_name, datatype, value)
    return out


def sync(cob_id: str, period_us: int) -> list[str]:
    return (var("1005", "COB-ID SYNC message", "0x0007", cob_id)
            + var("1006", "Communication cycle period", "0x0007", str(period_us)))


def rpdo1(cob_id: str, trans: str, event_ms: int) -> list[str]:
    """RPDO1 of 2001h:00 (u32); 1400h sub 5 = the deadline (event timer)."""
    return (record("1400", "RPDO1 communication parameter",
                   [("COB-ID used by RPDO", "0x0007", cob_id),
                    ("Transmission type", "0x0005", trans),
                    ("Inhibit time", "0x0006", "0"),
                    ("Reserved", "0x0005", "0"),
                    ("Event timer", "0x0006", str(event_ms))])
            + record("1600", "RPDO1 mapping parameter",
                     [("Mapped object 1", "0x0007", "0x20010020")]))


COUNTER_IN = var("2001", "Received counter", "0x0007", "0", pdo=1)
SYNC_MS = 50  # 1006h of producer and consumers: 50 ms

# name: (description, objects to add, {section: (key, value)} changes of slave.eds)
VARIANTS: dict[str, tuple[str, list[str], dict[str, tuple[str, str]]]] = {
    "rpdo_deadline.eds": (
        "RPDO1 = node 2's TPDO1 (182h, FEh) with a 750 ms deadline (1400h:05)",
        rpdo1("0x00000182", "0xFE", 750) + COUNTER_IN, {}),
    "sync_producer.eds": (
        f"SYNC producer (1005h = 40000080h), 1006h = {SYNC_MS} ms, no counter (1019h absent)",
        sync("0x40000080", SYNC_MS * 1000), {}),
    "sync_consumer.eds": (
        f"SYNC consumer (1005h = 80h) with 1006h = {SYNC_MS} ms",
        sync("0x00000080", SYNC_MS * 1000), {}),
    "sync_tpdo.eds": (
        f"SYNC consumer (1006h = {SYNC_MS} ms) whose TPDO1 is synchronous, every SYNC "
        "(1800h:02 = 1)",
        sync("0x00000080", SYNC_MS * 1000), {"1800sub2": ("DefaultValue", "0x01")}),
    "sync_rpdo.eds": (
        f"SYNC consumer (1006h = {SYNC_MS} ms) with RPDO1 = node 2's TPDO1 (182h), "
        "synchronous (type 1), no deadline",
        sync("0x00000080", SYNC_MS * 1000) + rpdo1("0x00000182", "0x01", 0) + COUNTER_IN, {}),
}


def _objects(extra: list[str]) -> list[int]:
    return [int(m.group(1), 16) for line in extra
            if (m := re.fullmatch(r"\[([0-9A-F]{4})\]", line))]


def variant(name: str, what: str, extra: list[str],
            subs: dict[str, tuple[str, str]]) -> str:
    text = BASE.read_text()
    lists: dict[str, list[int]] = {}
    for section in ("OptionalObjects", "ManufacturerObjects"):
        body = re.search(rf"\[{section}\]\n(.*?)\n\n", text, re.S)
        assert body
        lists[section] = [int(v.split("=")[1], 16) for v in body.group(1).splitlines()[1:]]
    for index in _objects(extra):
        lists["ManufacturerObjects" if index >= 0x2000 else "OptionalObjects"].append(index)
    out, section, skip = [], "", False
    for line in text.splitlines():
        m = re.match(r"\[(.+)\]$", line)
        if m:
            section = m.group(1)
            skip = section in lists
            if skip:
                objs = sorted(lists[section])
                out += [line, f"SupportedObjects={len(objs)}"]
                out += [f"{k}=0x{v:04X}" for k, v in enumerate(objs, 1)] + [""]
                continue
        if skip:
            continue
        key = line.split("=", 1)[0]
        if section in subs and key == subs[section][0]:
            line = f"{key}={subs[section][1]}"
        elif section == "FileInfo" and key == "FileName":
            line = f"FileName={name}"
        elif section == "FileInfo" and key == "Description":
            line = f"Description=nmtcheck Lely SYNC/PDO/EMCY recordings: {what}"
        elif section == "DeviceInfo" and key == "NrOfRxPDO" and "1400" in str(extra):
            line = "NrOfRxPDO=1"
        out.append(line)
    return "\n".join(out).rstrip("\n") + "\n\n" + "\n".join(extra).rstrip("\n") + "\n"


if __name__ == "__main__":
    here = Path(__file__).resolve().parent
    for file_name, (what, extra, subs) in VARIANTS.items():
        (here / file_name).write_text(variant(file_name, what, extra, subs))
