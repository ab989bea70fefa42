"""cellsim's version: what a run's provenance, a campaign's workers and the exports record."""

__version__ = "0.1.0"
