"""The point classes towerpipe reads and writes (ASPRS LAS 1.4 codes), defined here once.

The merge writes :data:`TOWER` on the points of a tower and :data:`OTHER` on those it takes
back from a former tower label; preprocessing drops :data:`NOISE` and takes :data:`GROUND`
as given; the wire detector and the inference treat :data:`WIRE` points as conductors;
evaluation reads :data:`TOWER` in the input as the truth.
"""

from __future__ import annotations

#: Created, never classified (what the merge writes on a former tower point it does not keep).
OTHER = 1
GROUND = 2
LOW_VEGETATION, MEDIUM_VEGETATION, HIGH_VEGETATION = 3, 4, 5
BUILDING = 6
LOW_NOISE = 7
ROAD = 11
WIRE_GUARD, WIRE_CONDUCTOR = 13, 14
#: Transmission tower: the class of the product's tower points.
TOWER = 15
HIGH_NOISE = 18

#: The first class LAS 1.4 leaves to the delivery (64-255; 23-63 are reserved): towerpipe takes such a
#: point as a point of the scene unless ``preprocess.extra_noise_classes`` lists its class.
USER_DEFINED_MIN = 64

#: Low, medium and high vegetation.
VEGETATION = (LOW_VEGETATION, MEDIUM_VEGETATION, HIGH_VEGETATION)
#: Low and high noise: dropped before the model.
NOISE = (LOW_NOISE, HIGH_NOISE)
#: Overhead wires (guard/shield and conductor/phase).
WIRE = (WIRE_GUARD, WIRE_CONDUCTOR)
