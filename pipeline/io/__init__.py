"""Files in and out: frame readers, training sequences, model files, and MCAP recordings
(write: :mod:`pipeline.io.recorder`; read: :mod:`pipeline.io.mcap_io`). Imports nothing else from ``pipeline``."""
