"""Write the slave EDS variants of the boot recordings from ../slave.eds (run here).

Each variant changes a few DefaultValues or an AccessType of slave.eds; the table in
README.md says which and why. Kept as a script so the difference is reviewable."""

import re
from pathlib import Path

BASE = Path(__file__).resolve().parent.parent / "slave.eds"

# identity of the slaves of identity/ (all four 1018h entries non-zero, device type too)
ID = {"1000": "0x00020192", "1018sub1": "0x00000360", "1018sub2": "0x00004E4D",
      "1018sub3": "0x00010002", "1018sub4": "0x0000BEEF"}
INFO = {"VendorNumber": "0x00000360", "ProductNumber": "0x00004E4D",
        "RevisionNumber": "0x00010002"}

VARIANTS: dict[str, tuple[str, dict[str, tuple[str, str]], dict[str, str]]] = {
    # name: (description, {section: (key, value)}, [DeviceInfo] changes)
    "slave_id.eds": ("the slave of identity/: device type and all of 1018h set",
                     {k: ("DefaultValue", v) for k, v in ID.items()}, INFO),
    "expect_C.eds": ("what identity/ expects of node 2: another device type",
                     {**{k: ("DefaultValue", v) for k, v in ID.items()},
                      "1000": ("DefaultValue", "0x00020191")}, INFO),
    "expect_D.eds": ("what identity/ expects of node 3: another vendor-ID",
                     {**{k: ("DefaultValue", v) for k, v in ID.items()},
                      "1018sub1": ("DefaultValue", "0x00000361")},
                     {**INFO, "VendorNumber": "0x00000361"}),
    "expect_M.eds": ("what identity/ expects of node 4: another product code",
                     {**{k: ("DefaultValue", v) for k, v in ID.items()},
                      "1018sub2": ("DefaultValue", "0x00004E4E")},
                     {**INFO, "ProductNumber": "0x00004E4E"}),
    "slave_ro1017.eds": ("a firmware whose 1017h is read-only (refuses the download)",
                         {"1017": ("AccessType", "ro")}, {}),
    "slave_nosdo.eds": ("a slave whose default SDO server is disabled (1200h:01 bit 31)",
                        {"1200sub1": ("DefaultValue", "$NODEID+0x80000600")}, {}),
    "slave_op.eds": ("a self-starting slave (1F80h = 0) with 1017h = 100 ms at power-on",
                     {"1F80": ("DefaultValue", "0x00000000"),
                      "1017": ("DefaultValue", "100")}, {}),
}


def variant(name: str, what: str, subs: dict[str, tuple[str, str]],
            info: dict[str, str]) -> str:
    out, section = [], ""
    for line in BASE.read_text().splitlines():
        m = re.match(r"\[(.+)\]$", line)
        if m:
            section = m.group(1)
        key = line.split("=", 1)[0]
        if section in subs and key == subs[section][0]:
            line = f"{key}={subs[section][1]}"
        elif section == "DeviceInfo" and key in info:
            line = f"{key}={info[key]}"
        elif section == "FileInfo" and key == "FileName":
            line = f"FileName={name}"
        elif section == "FileInfo" and key == "Description":
            line = f"Description=nmtcheck Lely boot recordings: {what}"
        out.append(line)
    return "\n".join(out) + "\n"


for name, (what, subs, info) in VARIANTS.items():
    Path(name).write_text(variant(name, what, subs, info))
