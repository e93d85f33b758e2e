"""gflow_core package."""
