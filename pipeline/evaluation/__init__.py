"""Scoring trackers on sequences with ground truth: ``gflow benchmark``'s runs, scores, tables
and JSON (:mod:`.sequence_benchmark`, :mod:`.benchmark_tables`) and its stress benchmark
(:mod:`.stress_benchmark`). The command itself is :mod:`pipeline.cli.commands.benchmark`."""
