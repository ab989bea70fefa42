"""What a run's black box shows of harm: every contact, and the closest approach of a robot to a person."""

from __future__ import annotations

import math

import numpy as np

from cellsim.kind import Finding
from cellsim.kinds.harm.system import NONE


def _series(bb, channel):
    return bb.series(channel) if channel in bb.channels() else None


def harm_findings(name: str, bb, max_part_speed: float | None = None) -> list[Finding]:
    """The contacts (each interval the worst contact's region is not none, with its worst severity), the closest
    approach (the least separation of any robot, where and when), and where the service's assumptions between two
    looks broke: a robot part seen faster than ``max_part_speed`` (m/s), a body region that jumped farther than it and
    a part are thick."""
    region = _series(bb, f"{name}.contact_region")
    if region is None:
        return []
    others = {key: _series(bb, f"{name}.{key}") for key in ("severity", "contact_person", "contact_part", "contact_kind",
                                                            "contact_speed", "nearest_region", "nearest_person")}
    found = []
    touching = [region] + [others[key] for key in ("contact_person", "contact_part") if others[key] is not None]
    start, held = None, None  # the contact under way: when it began, and its (region, person, part)
    for t in sorted({float(t) for series in touching for t in series.times.tolist()}):
        now = tuple(series.value_at(t) for series in touching)
        if now == held:
            continue
        if start is not None:  # another region, person or part is another contact (a hand, then its forearm)
            found.append(_contact(name, others, region, start, t))
        start, held = (t, now) if now[0] != NONE else (None, None)
    if start is not None:
        found.append(_contact(name, others, region, start, None))
    approach = _closest(name, bb, others, [f for f in found if f.what == "contact"])
    unseen = [f for f in (_too_fast(name, bb, max_part_speed), _jumped(name, bb)) if f is not None]
    return ([approach] if approach is not None else []) + found + unseen


def _jumped(name, bb) -> Finding | None:
    """When a body region first moved farther in one of its person's updates, near a robot, than it and the thinnest
    robot part are thick together (``region_jump`` above 0), and the most it did."""
    seen = _series(bb, f"{name}.region_jump")
    if seen is None or not len(seen):
        return None
    beyond = np.array([v if isinstance(v, (int, float)) else np.inf for v in seen.values], float)
    if not beyond[-1] > 0.0:
        return None
    first = int(np.argmax(beyond > 0.0))
    most = float(beyond[-1])
    text = (f"a body region moved {most:.3g} m farther in one of its person's updates, near a robot, than it and the "
            f"thinnest robot part are thick together: the harm service sees it where each update puts it, so it may "
            f"have passed through a part unseen (lower the person's turn_rate or period; docs/harm.md)")
    return Finding(name, "region jump", float(seen.times[first]), None, text, {"beyond": most})


def _too_fast(name, bb, max_part_speed) -> Finding | None:
    """When a look first found a robot part faster than ``max_part_speed`` after an interval the service watched only
    at its looks (it had sped up by more than half of it within one), and the fastest such."""
    seen = _series(bb, f"{name}.unwatched_part_speed")
    if seen is None or max_part_speed is None or not len(seen):
        return None
    speeds = np.array([v if isinstance(v, (int, float)) else np.inf for v in seen.values], float)
    if not speeds[-1] > max_part_speed:
        return None
    first = int(np.argmax(speeds > max_part_speed))
    fastest = float(speeds[-1])
    text = (f"a robot part moved at {fastest:.3g} m/s at the end of an interval the harm service watched only at its "
            f"looks, above the {max_part_speed:g} m/s it assumes there: a contact in it may have been missed (raise "
            f"{name}.max_part_speed and shorten {name}.far_period to suit)")
    return Finding(name, "fast part", float(seen.times[first]), None, text,
                   {"speed": fastest, "max_part_speed": max_part_speed})


def _contact(name, others, region, start, end) -> Finding:
    severity = others["severity"]
    inside = (severity.times >= start) & ((severity.times < end) if end is not None else True)
    times = severity.times[inside].tolist()
    values = [severity.values[i] for i in np.flatnonzero(inside)]
    if not values:  # the contact's severity is what held when it began
        times, values = [start], [severity.value_at(start)]
    worst = int(np.argmax(values))
    at = times[worst]
    data = {
        "severity": float(values[worst]),
        "region": region.value_at(at),
        "person": others["contact_person"].value_at(at),
        "part": others["contact_part"].value_at(at),
        "kind": others["contact_kind"].value_at(at),
        "speed": float(others["contact_speed"].value_at(at)),
        "worst_at": at,
    }
    harm = "HARM" if data["severity"] > 1 else "within the limit"
    text = (f"{data['kind'].replace('_', '-')} contact of {data['part']} with {data['person']}'s {data['region'].replace('_', ' ')} "
            f"at {data['speed']:.3g} m/s: severity {data['severity']:.3g} ({harm})")
    return Finding(name, "contact", start, end, text, data)


def _closest(name, bb, others, contacts: list[Finding] = ()) -> Finding | None:
    """The least separation of any robot from anybody, where and when; a touch (0 or less) with the speed and
    severity of the contact it belongs to at that contact's worst (at the deepest overlap itself the region may be
    parting: severity 0)."""
    best = None
    for channel in bb.channels():
        if not channel.startswith(f"{name}.separation_"):
            continue
        series = bb.series(channel)
        if not len(series):
            continue
        i = int(np.argmin(series.values))
        if best is None or series.values[i] < best[0]:
            best = (float(series.values[i]), float(series.times[i]), channel.removeprefix(f"{name}.separation_"))
    if best is None:
        return None
    distance, t, robot = best
    region = others["nearest_region"].value_at(t) if others["nearest_region"] is not None else None
    if region in (None, NONE):
        return Finding(name, "closest approach", t, None, f"no robot came within {distance:.3g} m of anybody",
                       {"distance": distance, "robot": robot})
    person = others["nearest_person"].value_at(t) if others["nearest_person"] is not None else NONE
    whose = "a person's" if person == NONE else f"{person}'s"  # (a black box from before the channel: no person)
    data = {"distance": distance, "robot": robot, "region": region, "severity": 0.0,
            **({"person": person} if person != NONE else {})}
    text = f"{robot} came within {distance:.3g} m of {whose} {region.replace('_', ' ')} at {t:.3f} s"
    tool = f"{robot}.tool_speed"
    if distance > 0 and tool in bb.channels():  # a near miss: how fast the arm was going then, where it is known
        series = bb.series(tool)  # (a physical robot gone silent: unknown)
        speed = series.value_at(t) if len(series) else None
        if isinstance(speed, (int, float)) and math.isfinite(speed):
            data["tool_speed"] = float(speed)
            text += f", its tool at {data['tool_speed']:.3g} m/s"
    during = next((c for c in contacts if c.start <= t and (c.end is None or t < c.end)), None) if distance <= 0 else None
    if during is not None:
        worst = during.data
        data.update(severity=worst["severity"], speed=worst["speed"], person=worst["person"], region=worst["region"],
                    worst_at=worst["worst_at"])
        text = (f"{robot} touched {worst['person']}'s {worst['region'].replace('_', ' ')} at {t:.3f} s, "
                f"{-distance:.3g} m deep: at its worst ({worst['worst_at']:.3f} s) {worst['speed']:.3g} m/s, "
                f"severity {worst['severity']:.3g}")
    elif distance <= 0:
        text = f"{robot} touched {whose} {region.replace('_', ' ')} at {t:.3f} s"
    return Finding(name, "closest approach", t, None, text, data)
