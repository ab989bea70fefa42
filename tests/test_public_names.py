"""No public name of ``cellsim`` is shadowed by one of its packages: once a package named like an API function is
imported (``cellsim.campaign``, ``cellsim.verify``), Python sets the package as the attribute, so the API cannot
use such a name (it has ``run_campaign`` and ``verify_cell``)."""

from __future__ import annotations

import importlib
import pkgutil
import types

import cellsim


def test_no_public_name_is_a_package_once_every_package_is_imported():
    for found in pkgutil.walk_packages(cellsim.__path__, "cellsim."):
        if not found.name.endswith("__main__") and not found.name.startswith(
                ("cellsim.kinds.", "cellsim.bridges.", "cellsim.live.", "cellsim.dashboard.")):
            importlib.import_module(found.name)
    api = importlib.import_module("cellsim.api")
    shadowed = [name for name in cellsim.__all__ if isinstance(getattr(cellsim, name), types.ModuleType)]
    assert not shadowed
    assert all(getattr(cellsim, name) is getattr(api, name) for name in cellsim.__all__)
