from nmtcheck.cli import main

main()
