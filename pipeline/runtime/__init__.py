"""Running a graph: graph files, zenoh transport, stage processes and their launcher, the stage
host, in-process runs. Imports only :mod:`pipeline.io` from ``pipeline``."""
