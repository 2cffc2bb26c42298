"""The `imud` command (`imud.cli.commands`) and what it prints (`*_view`)."""
