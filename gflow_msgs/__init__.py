"""gflow's messages: the contract between stages, recordings and other programs.

``messages.py`` holds the tagged union every stage sends (:data:`~gflow_msgs.messages.Message`),
its encoder and decoder and their JSON schemas; ``base.py`` the header, box and array types;
``gflow.py`` G-flow's messages; ``foxglove.py`` Foxglove's well-known schemas;
``annotations.py`` an estimate's overlays in them; ``params.py`` the stages' parameter structs and
``source.py`` what a source reads and hands on (graph files and the frame readers share them with
the stages); ``snapshots.py`` the stages' snapshots. This package imports
msgspec, numpy and the standard library only (``tests/test_layering.py``), so a program that reads
a recording needs nothing else of gflow.
"""
