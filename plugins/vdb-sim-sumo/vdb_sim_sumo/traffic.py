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


@dataclass(frozen=True)
class TrafficDensity:
    """How much background traffic: vehicles and pedestrians per hour over the whole network."""

    vehicles_per_hour: float = 0.0
    pedestrians_per_hour: float = 0.0

    @property
    def empty(self) -> bool:
        return self.vehicles_per_hour <= 0 and self.pedestrians_per_hour <= 0


@dataclass(frozen=True)
class Trip:
    """One origin-destination pair of the background traffic: ``name`` (unique) and its two edges."""

    name: str
    origin: str
    destination: str


def trips_between(ends: tuple[RoadEnd, ...], sidewalks: bool) -> tuple[list[Trip], list[Trip]]:
    """Vehicle trips from every end of the network to every other end, and walks between every pair of ends
    (a walk from an end back to the same end crosses the road there, or walks back on the other side)."""
    drives = [Trip(f"{a.name}-{b.name}", a.enter, b.leave) for a in ends for b in ends if a.name != b.name]
    walks = [Trip(f"{a.name}-{b.name}", a.enter, b.leave) for a in ends for b in ends] if sidewalks else []
    return drives, walks


def routes_xml(drives: list[Trip], walks: list[Trip], density: TrafficDensity, end_s: float) -> str:
    """A SUMO routes file with the vehicle types and the flows of ``density`` over ``drives`` and ``walks``,
    from time 0 to ``end_s``. (Flows end with the episode: SUMO lists persons slower the longer a person
    flow lasts, 70 ms per step for a flow that never ends.)"""
    car_l, car_w, car_h = CAR_SIZE
    ped_l, ped_w, ped_h = PEDESTRIAN_SIZE
    lines = [
        "<routes>",
        f'    <vType id="bg.car" vClass="passenger" length="{car_l}" width="{car_w}" height="{car_h}" '
        'speedDev="0.1"/>',
        f'    <vType id="bg.ped" vClass="pedestrian" length="{ped_l}" width="{ped_w}" height="{ped_h}"/>',
    ]
    if drives and density.vehicles_per_hour > 0:
        rate = density.vehicles_per_hour / len(drives) / 3600.0
        for trip in drives:
            lines.append(
                f"    <flow id={quoteattr(f'{BACKGROUND_PREFIX}car.{trip.name}')} type=\"bg.car\" "
                f"from={quoteattr(trip.origin)} to={quoteattr(trip.destination)} begin=\"0\" "
                f'end="{end_s:g}" period="exp({rate:.9g})" departLane="best" departSpeed="max"/>'
            )
    if walks and density.pedestrians_per_hour > 0:
        rate = density.pedestrians_per_hour / len(walks) / 3600.0
        for trip in walks:
            # A walk starts anywhere along its first edge and ends anywhere along its last.
            lines.append(
                f"    <personFlow id={quoteattr(f'{BACKGROUND_PREFIX}ped.{trip.name}')} type=\"bg.ped\" "
                f'begin="0" end="{end_s:g}" period="exp({rate:.9g})" departPos="random">'
                f"<walk from={quoteattr(trip.origin)} to={quoteattr(trip.destination)} arrivalPos=\"random\"/>"
                "</personFlow>"
            )
    lines.append("</routes>")
    return "\n".join(lines) + "\n"
