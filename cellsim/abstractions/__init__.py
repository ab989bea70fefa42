"""What each of cellsim's module kinds is in the abstract model ``cellsim verify`` checks.

One module per family of kinds; each kind names its abstraction in its
``ModuleKind`` (``abstraction=deferred("cellsim.abstractions.<module>:<name>")``),
so nothing here is imported until a scenario is verified.
"""
