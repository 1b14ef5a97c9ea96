from nmtcheck.cli.main import command

command()
