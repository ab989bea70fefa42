"""The area_scanner kind: a safety laser scanner with named fields."""

from __future__ import annotations

from cellsim.entity import TWIN_CHANNELS
from cellsim.kinds.area_scanner.config import AreaScannerConfig
from cellsim.kinds.area_scanner.system import AreaScanner
from cellsim.kinds.sensing import add_sensor
from cellsim.channels import enum_type, number_type
from cellsim.kind import ModuleKind, Protocol
from cellsim.vocabulary import value_set


class AreaScannerKind(ModuleKind):
    name = "area_scanner"
    section = "entities"
    config = AreaScannerConfig
    summary = "A safety laser scanner with named fields (boxes or extruded polygons): the innermost field a person is seen in."
    sample_fields = ("field", "distance")
    channels = (
        ("field", "enum", "the innermost field a person is seen in (not through fixtures), else the clear reading"),
        ("distance", "number, m", "distance to the nearest person seen, at most max_range"),
        ("unseen", "enum", "blind spot: the innermost field a person truly meets that the reading does not cover, else none"),
        *TWIN_CHANNELS,
    )

    def protocol(self, name, cfg):
        fields = enum_type(value_set(f"{name}_field", [cfg.clear, *cfg.fields]))
        return Protocol((("field", fields), ("distance", number_type(None))))

    def build(self, cell, name, cfg):
        return add_sensor(cell, name, AreaScanner(name, cfg, cell.scenario.layout.fixtures.values()))

    def check(self, sf, name, cfg):
        """The scanner and every corner of its fields lie within the cell (its layout's extent)."""
        _check(sf, name, cfg)

    def findings(self, name, cfg, blackbox):
        from cellsim.kinds.sensing import blind_spots

        return blind_spots(name, blackbox, f"{name}.unseen")

    def abstraction(self, abstract, name, cfg):
        from cellsim.kinds.area_scanner.abstraction import AreaScannerAbstraction

        return AreaScannerAbstraction(abstract, name, cfg)


def _check(sf, name: str, cfg: AreaScannerConfig) -> None:
    """The scanner and every corner of its fields lie within the cell (its layout's extent)."""
    extent = sf.scenario.layout.extent()
    if extent is None:
        return
    lo, hi = extent
    key = f"entities.{name}"
    if not all(a - 1e-9 <= x <= b + 1e-9 for a, x, b in zip(lo, cfg.position, hi)):
        raise sf.error(f"{key}.position", f"{list(cfg.position)} is outside the cell (its layout spans {list(lo)} to {list(hi)})")
    for field_name, spec in cfg.fields.items():
        for corner in spec.corners():
            if not all(a - 1e-9 <= x <= b + 1e-9 for a, x, b in zip(lo, corner, hi)):
                raise sf.error(
                    f"{key}.fields.{field_name}",
                    f"the field reaches {list(corner)}, outside the cell (its layout spans {list(lo)} to {list(hi)})",
                )
