"""Bytecode for the checkout a bench times (issue 25): a measured `nmtcheck` process must
import what a user's installation has, compiled modules. pip writes bytecode when it
installs; an editable checkout gets it at a module's first import, unless the environment
sets PYTHONDONTWRITEBYTECODE (this VM does): then every changed module was compiled
again in every measured process, 8 ms per start-up for two modules on 2026-11-27.
"""

from __future__ import annotations

import compileall
import os
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def ensure_bytecode(checkout: Path = REPO) -> str:
    """Compile `checkout`'s package (what is already fresh is left alone); a line that
    says so, for the bench's header."""
    compileall.compile_dir(str(checkout / "nmtcheck"), quiet=1, workers=0)
    flag = os.environ.get("PYTHONDONTWRITEBYTECODE")
    return ("bytecode compiled for nmtcheck/ (PYTHONDONTWRITEBYTECODE is set here)" if flag
            else "bytecode compiled for nmtcheck/")
