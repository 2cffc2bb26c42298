from imud.cli.commands import main

main()
