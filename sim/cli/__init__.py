"""The `pixelswarm` command line: its subcommands and their arguments. May import every other part of sim."""
