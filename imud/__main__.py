from imud.cli import main

main()
