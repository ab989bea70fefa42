"""``cellsim live``: the scenario twin paced to the wall clock, beside the real cell, on Zenoh.

The builder makes it (``cellsim.diagrams.cell.build_cell`` with ``cellsim.cell_io.Live``),
with the Zenoh systems of ``cellsim.live.systems`` in the diagram:

* every entity takes its physical samples from its physical key through a
  ``ZenohSampleSource`` (whatever its twin mode now: the mode may change while the
  twin runs), judged by the one link-trust rule (``cellsim.link``);
* every channel that changed is published every ``TICK`` (and every channel every
  ``HEARTBEAT``); the commands of each entity in twin mode one plant step after
  the update that changes them (in shadow and model mode nothing is sent);
* twin-mode requests (a Zenoh query on the control key) are answered at once,
  accepted or refused with the reason, and applied at the entity's next update,
  recording who asked;
* its status every second: pacing lag (wall clock minus simulated time), the age
  of each entity's newest sample; and :func:`describe`, on a query, for a dashboard.

Its clock starts once every entity in shadow or twin mode has been heard from
(at most ``wait_physical`` seconds), so a twin started before the cell does not
record a start-up spent failing safe as safety evidence.

Its black box is recorded as in any run; ``live`` in its metadata holds the mode
requests and the pacing figures.
"""

from __future__ import annotations


def describe(sf, channels: dict, modules: dict) -> dict:
    """What a running twin tells a dashboard about itself (the ``describe`` query's answer): the
    resolved scenario, every channel as the black box lists it, and the hazards' phases."""
    from cellsim.config.typed_yaml import to_data
    from cellsim.systems import hazard_phases

    described = {
        spec.name: {"source": spec.module, "kind": spec.type.kind, "domain": spec.type.domain(), "unit": spec.type.unit,
                    "period": spec.sample_period, "description": spec.description}
        for spec, _ in channels.values()
    }
    return {"scenario": to_data(sf.scenario), "channels": described, "hazards": hazard_phases(modules.values())}
