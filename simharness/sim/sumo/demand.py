"""SUMO demand from a `ScenarioSpec`: vTypes per agent type with a spread of drivers, and Poisson flows.

vType ids are "<agent type>__<level>" (level 0 aggressive .. LEVELS-1 conservative), grouped in a
vTypeDistribution "<agent type>" per type, so a recorded vType maps back to its `AgentType` by
the text before "__". Pedestrians are sub-lane vehicles of type "pedestrian__*" on the carriageway
(see pedestrians.py for why).
"""

from __future__ import annotations

from simharness.scenario import EVENT_ACTORS, ScenarioSpec
from simharness.scene import DEFAULT_FOOTPRINT, AgentType
from simharness.sim.sumo.net import Network

LEVELS = 3  # drivers per type: aggressive, normal, conservative
LEVEL_SHARE = (0.25, 0.5, 0.25)
TURN_ALIGNMENT = 20.0  # m before a turn (intersection): measured, it halved junction collisions with left turns

# Per type: vClass, guiShape, maxSpeed (m/s), accel, decel (m/s^2), minGap (m), maxSpeedLat (m/s), tau (s)
KINEMATICS: dict[AgentType, tuple[str, str, float, float, float, float, float, float]] = {
    AgentType.CAR: ("passenger", "passenger", 16.7, 2.6, 4.5, 2.0, 1.0, 1.0),
    AgentType.BUS: ("bus", "bus", 13.9, 1.2, 4.0, 2.5, 0.6, 1.2),
    AgentType.TRUCK: ("truck", "truck", 13.9, 1.3, 4.0, 2.5, 0.6, 1.2),
    AgentType.RICKSHAW: ("taxi", "rickshaw", 11.1, 1.8, 4.0, 1.5, 1.0, 1.0),
    AgentType.MOTORCYCLE: ("motorcycle", "motorcycle", 16.7, 3.5, 6.0, 1.0, 1.6, 0.8),
    AgentType.SCOOTER: ("moped", "moped", 12.5, 2.8, 5.5, 1.0, 1.5, 0.8),
    AgentType.BICYCLE: ("bicycle", "bicycle", 6.0, 1.2, 3.0, 0.8, 1.0, 0.9),
    AgentType.PEDESTRIAN: ("custom1", "pedestrian", 2.5, 1.5, 2.5, 0.4, 1.5, 0.8),
    AgentType.OTHER: ("passenger", "passenger/van", 13.9, 2.0, 4.5, 2.0, 0.8, 1.0),
}


def agent_type_of(vtype_id: str) -> AgentType:
    """The `AgentType` of a vType id written by `vtypes_xml` ("car__1" -> CAR, "ego" types too)."""
    return AgentType[vtype_id.split("__", 1)[0].upper()]


def _vtype(t: AgentType, level: int, spec: ScenarioSpec, vid: str | None = None) -> str:
    vclass, shape, vmax, accel, decel, min_gap, vlat, tau = KINEMATICS[t]
    length, width = DEFAULT_FOOTPRINT[t]
    # u in [-1, 1]: +1 aggressive (faster, shorter headway, harder accel), -1 conservative.
    u = (1.0 - 2.0 * level / (LEVELS - 1)) * spec.behaviour.spread if LEVELS > 1 else 0.0
    attrs = {
        "id": vid or f"{t.label}__{level}", "vClass": vclass, "guiShape": shape,
        "length": f"{length:.2f}", "width": f"{width:.2f}", "minGap": f"{min_gap * (1 - 0.35 * u):.2f}",
        "maxSpeed": f"{vmax:.2f}", "accel": f"{accel * (1 + 0.3 * u):.2f}", "decel": f"{decel * (1 + 0.2 * u):.2f}",
        "emergencyDecel": f"{max(9.0, decel * 2):.1f}", "tau": f"{tau * (1 - 0.4 * u):.2f}",
        "sigma": f"{0.4 + 0.1 * u:.2f}", "speedFactor": f"norm({1 + 0.15 * u:.3f},{spec.behaviour.speed_dev:.3f})",
        "maxSpeedLat": f"{vlat * (1 + 0.3 * u):.2f}", "latAlignment": "arbitrary",
        "minGapLat": f"{spec.sublane.min_gap_lat * (1 - 0.3 * u):.2f}",
        "lcStrategic": "1.0", "lcCooperative": f"{0.8 - 0.3 * u:.2f}", "lcSpeedGain": f"{1.0 + 0.5 * u:.2f}",
        "lcKeepRight": "0", "lcOvertakeRight": "1", "lcLaneDiscipline": f"{spec.sublane.lane_discipline:.2f}",
        # Filtering without pushing: lcPushy > 0 collided with marked lanes (measured).
        "lcPushy": "0", "lcAssertive": "1", "lcSigma": "0", "lcImpatience": "0",
        "lcSublane": f"{1.0 + 0.5 * u:.2f}",
        # Move to the side of a coming turn: right- and left-turners from one approach do not cross in a junction.
        "lcTurnAlignmentDistance": f"{TURN_ALIGNMENT:.1f}",
    }
    if t is AgentType.PEDESTRIAN:
        ped = spec.pedestrians
        attrs |= {"maxSpeed": f"{ped.speed * 1.6:.2f}", "desiredMaxSpeed": f"{ped.speed:.2f}",
                  "speedFactor": "norm(1,0.15,0.5,1.5)", "latAlignment": "right", "minGapLat": "0.3"}
    elif t is AgentType.BICYCLE:
        attrs["desiredMaxSpeed"] = f"{4.5 * (1 + 0.15 * u):.2f}"
    return "<vType " + " ".join(f'{k}="{v}"' for k, v in attrs.items()) + "/>"


def vtypes_xml(spec: ScenarioSpec, types: list[AgentType]) -> str:
    """vTypes and one vTypeDistribution per agent type (aggressive .. conservative drivers)."""
    out = []
    for t in types:
        members = [f"{t.label}__{k}" for k in range(LEVELS)]
        out += ["  " + _vtype(t, k, spec) for k in range(LEVELS)]
        out.append(f'  <vTypeDistribution id="{t.label}" vTypes="{" ".join(members)}" '
                   f'probabilities="{" ".join(str(p) for p in LEVEL_SHARE)}"/>')
    return "\n".join(out)


def ego_vtype_xml(spec: ScenarioSpec) -> str:
    """The ego's own vType ("<type>__ego"): the normal driver of its agent type."""
    return "  " + _vtype(AgentType.parse(spec.ego.type), LEVELS // 2, spec, vid=f"{spec.ego.type}__ego")


def routes_xml(spec: ScenarioSpec, net: Network, end: float) -> str:
    """The whole .rou.xml: vTypes, routes, one Poisson flow per (type, route) from t=0 to `end`.

    Demand is vehicles per hour for the whole network, split evenly over the entry carriageways,
    then over each entry's routes by turning share. Pedestrians walking along the road are flows
    of the pedestrian vType kept to the right edge; crossing pedestrians are inserted at run time.
    """
    flows = {t: v for t, v in spec.flows().items() if v > 0}
    walking = spec.pedestrians.walking_rate * spec.demand_scale
    crossing = spec.pedestrians.crossing_rate * spec.demand_scale
    actors = {AgentType.parse(e.actor or EVENT_ACTORS[e.kind]) for e in spec.events}  # scripted: events.py
    actors |= {AgentType.BUS for e in spec.events if e.kind == "step_out"}
    types = sorted(set(flows) | ({AgentType.PEDESTRIAN} if walking + crossing > 0 else set()) | actors)
    lines = ["<routes>", vtypes_xml(spec, types)]
    if spec.ego.enabled:
        lines.append(ego_vtype_xml(spec))
    for rid, edges in net.routes.items():
        lines.append(f'  <route id="{rid}" edges="{" ".join(edges)}"/>')
    n_entries = len(net.entries)
    for t, per_hour in [*flows.items(), *([(AgentType.PEDESTRIAN, walking)] if walking > 0 else [])]:
        lat = "right" if t is AgentType.PEDESTRIAN else "random_free"
        for routes in net.entry_routes.values():
            for rid, share in routes:
                rate = per_hour * share / n_entries / 3600.0  # vehicles per second
                if rate <= 0:
                    continue
                lines.append(f'  <flow id="{t.label}.{rid}" type="{t.label}" route="{rid}" begin="0" end="{end:.1f}" '
                             f'period="exp({rate:.6f})" departLane="random" departPosLat="{lat}" '
                             f'departSpeed="{"max" if t is not AgentType.PEDESTRIAN else "desired"}"/>')
    lines.append("</routes>\n")
    return "\n".join(lines)
