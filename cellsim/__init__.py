"""cellsim: scenario digital twins of collaborative robot cells, for safety assurance.

A scenario (YAML, or dataclasses built in Python) describes a cell's layout, its entities (robot,
welder, sensors, people) with their twin modes, its behaviours (process and safety controllers,
analyses) and its services (harm, recording). From a script::

    import cellsim

    sf = cellsim.load_scenario("scenarios/welding_cell.yaml", ["seed=3"])
    run = cellsim.simulate(sf, "runs/welding")
    run.verdicts                              # each condition's verdict on the run
    run.dataframe(["ground_truth.separation"])  # the trace, as pandas

Every name here is :mod:`cellsim.api`'s (docs/scripting.md, docs/api.md); the names are loaded when
first used: ``import cellsim`` does not import Drake until a name that needs it is.
"""

from cellsim.version import __version__  # noqa: F401

from cellsim.names import PUBLIC as __all__  # noqa: E402  (the public names; each loaded when first used)


def __getattr__(name: str):
    if name in __all__:
        from cellsim import api

        return getattr(api, name)
    raise AttributeError(f"module 'cellsim' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*__all__, "__version__"])
