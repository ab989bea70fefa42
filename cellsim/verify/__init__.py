"""Verification of a cell's safety controller in an abstract model of the cell (PRISM, Storm).

``prism`` writes guarded-command MDPs in the PRISM language; ``expressions``
translates the condition language into PRISM expressions; ``risk`` takes a risk
model, exactly as the engine executes it, into PRISM modules.
"""
