"""The `nmtcheck` command: `main.py` is the group and its `check`, `timeline` and `rules`
subcommands; `common.py` is what every subcommand shares (exit codes, safe output). The
package itself stays empty, so that `monitor` and `fleet` import `common` without loading
the group."""
