"""The terminal dashboard of a cell in operation (``cellsim dashboard``)."""
