"""One module per ``gflow`` command (or family of commands). Each has ``register(sub)``,
which adds its subparser(s) and sets ``func``. ``pipeline/cli.py`` lists them in order."""
