"""The ``gflow`` command line (:mod:`pipeline.cli.main`), its commands, tracker presets and live
tools. The top layer: nothing else in ``pipeline`` imports it."""
