"""Background traffic: SUMO's own vehicles and pedestrians, from every end of the network to every other.

Arrivals are Poisson (SUMO's ``period="exp(rate)"``) drawn from SUMO's random-number generator, which
the simulator seeds from the episode's seed, so the same seed gives the same traffic. The rates are per
hour for the whole network, split evenly over the (origin, destination) pairs. SUMO drives them with its
own models: car following, lane changing, junction right of way, the frozen traffic light, the stop
sign, pedestrians on sidewalks and crossings.
"""

from __future__ import annotations

from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

from .network import RoadEnd

BACKGROUND_PREFIX = "bg."
"""SUMO ids of background road users start with this; they appear in the ground truth under that id."""
CAR_SIZE = (4.6, 1.9, 1.5)
PEDESTRIAN_SIZE = (0.5, 0.6, 1.75)
FLOW_END_S = 1.0e6


@dataclass(frozen=True)
class TrafficDensity:
    """How much background traffic: vehicles and pedestrians per hour over the whole network."""

    vehicles_per_hour: float = 0.0
    pedestrians_per_hour: float = 0.0

    @property
    def empty(self) -> bool:
        return self.vehicles_per_hour <= 0 and self.pedestrians_per_hour <= 0


def routes_xml(ends: tuple[RoadEnd, ...], density: TrafficDensity, sidewalks: bool) -> str:
    """A SUMO routes file with the vehicle types and the flows of ``density`` between ``ends``."""
    car_l, car_w, car_h = CAR_SIZE
    ped_l, ped_w, ped_h = PEDESTRIAN_SIZE
    lines = [
        "<routes>",
        f'    <vType id="bg.car" vClass="passenger" length="{car_l}" width="{car_w}" height="{car_h}" '
        'speedDev="0.1"/>',
        f'    <vType id="bg.ped" vClass="pedestrian" length="{ped_l}" width="{ped_w}" height="{ped_h}"/>',
    ]
    pairs = [(a, b) for a in ends for b in ends if a.name != b.name]
    if pairs and density.vehicles_per_hour > 0:
        rate = density.vehicles_per_hour / len(pairs) / 3600.0
        for a, b in pairs:
            lines.append(
                f"    <flow id={quoteattr(f'{BACKGROUND_PREFIX}car.{a.name}-{b.name}')} type=\"bg.car\" "
                f"from={quoteattr(a.enter)} to={quoteattr(b.leave)} begin=\"0\" end=\"{FLOW_END_S:g}\" "
                f'period="exp({rate:.9g})" departLane="best" departSpeed="max"/>'
            )
    walks = [(a, b) for a in ends for b in ends] if sidewalks else []
    if walks and density.pedestrians_per_hour > 0:
        rate = density.pedestrians_per_hour / len(walks) / 3600.0
        for a, b in walks:
            # A walk starts anywhere along its first edge and may end on the same road's other side.
            lines.append(
                f"    <personFlow id={quoteattr(f'{BACKGROUND_PREFIX}ped.{a.name}-{b.name}')} type=\"bg.ped\" "
                f'begin="0" end="{FLOW_END_S:g}" period="exp({rate:.9g})" departPos="random">'
                f"<walk from={quoteattr(a.enter)} to={quoteattr(b.leave)} arrivalPos=\"random\"/></personFlow>"
            )
    lines.append("</routes>")
    return "\n".join(lines) + "\n"
