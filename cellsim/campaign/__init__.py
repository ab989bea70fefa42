"""Test campaigns: sampled scenario variants simulated and checked in worker processes."""

SEARCH_METHODS = ("cmaes", "qd", "random")
"""The searches a falsification runs (:mod:`cellsim.campaign.falsify`)."""
DEFAULT_SEARCH = "qd"
"""The search ``cellsim falsify`` and ``cellsim.falsify`` run unless told otherwise (docs/falsify.md says why).
Here, not in the search's module, so that the command line names it without importing the search."""
