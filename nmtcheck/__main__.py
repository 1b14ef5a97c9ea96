from nmtcheck.cli import command

command()
