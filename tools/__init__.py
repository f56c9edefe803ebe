"""Command-line tools of aider-exo (``aider-exo`` and its subcommands) and developer scripts."""
