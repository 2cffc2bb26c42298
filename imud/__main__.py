from imud.cli.commands import main

if __name__ == "__main__":  # not when a bus process re-imports the main module
    main()
