"""Scene parameters of the synthetic airborne generator and their presets.

All knobs of :func:`towerpipe.synth.generate_zone` live in :class:`SceneParams`
(a frozen dataclass); :func:`preset` returns a named set ("catalonia", "flat",
"mountain", "urban", "test") and :func:`with_overrides` changes a few fields.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from towerpipe.errors import ConfigError


@dataclass(frozen=True)
class SceneParams:
    """Every parameter of a synthetic scene (lengths in metres, angles in degrees).

    Attributes are grouped by concept: terrain, vegetation, buildings, roads,
    power lines, hard negatives, noise and sensor. Densities of objects are per
    km² unless said otherwise.
    """

    # terrain
    base_elevation: tuple[float, float] = (80.0, 1200.0)
    max_slope_deg: float = 25.0
    terrain_wavelength: tuple[float, float] = (150.0, 2500.0)
    terrain_res: float = 2.0
    # vegetation
    forest_cover: float = 0.45
    forest_scale: float = 180.0
    forest_tree_density: float = 0.055  # trees per m² inside forest
    forest_height: tuple[float, float] = (4.5, 9.5)
    forest_crown_ratio: tuple[float, float] = (0.28, 0.45)  # crown radius / height
    tall_tree_share: float = 0.08  # forest trees drawn from tall_height
    tall_height: tuple[float, float] = (10.0, 22.0)
    shrub_density: float = 0.05  # shrubs per m² (understory and open land)
    shrub_height: tuple[float, float] = (0.4, 3.0)
    scattered_trees: float = 300.0  # per km² outside forests
    isolated_tall_trees: float = 6.0  # per km², 18-30 m (hard negatives)
    canopy_gap: float = 0.18  # probability a pulse passes a crown untouched
    canopy_transmission: float = 0.35  # probability of a ground return under canopy
    corridor_clearing: float = 0.8  # share of trees under wires cut to <= 3 m
    # buildings and roads
    villages: float = 0.8  # per km²
    village_buildings: tuple[int, int] = (8, 40)
    scattered_buildings: float = 6.0  # per km²
    building_height: tuple[float, float] = (3.0, 14.0)
    tall_building_share: float = 0.06  # drawn from 14-30 m
    flat_roof_share: float = 0.45
    roads: float = 1.5  # per km²
    road_width: tuple[float, float] = (4.0, 9.0)
    # power lines
    lines_per_km2: float = 1.2
    min_lines: int = 1
    span: tuple[float, float] = (200.0, 400.0)
    deflections: tuple[int, int] = (0, 2)
    parallel_line_share: float = 0.3  # lines doubled parallel_gap m aside
    parallel_gap: tuple[float, float] = (24.0, 38.0)
    # the share of doubled lines whose towers stand beside the first line's (same stations, 0-2 m
    # along), as where two lines leave a substation together; the rest place their own
    twin_beside_share: float = 0.0
    designs: tuple[str, ...] = ("lattice_waist", "double_circuit", "small_lattice", "monopole")
    design_weights: tuple[float, ...] = (0.35, 0.3, 0.2, 0.15)
    edge_tower: bool = False  # force one tower straddling an inner block edge
    catenary_a: tuple[float, float] = (900.0, 2200.0)
    # stringing (towerpipe.synth.wires.strung): the share of double-circuit lines that carry one
    # circuit only, all on one side of their towers, and the share of lines without an earth wire
    one_side_share: float = 0.0
    no_earth_wire_share: float = 0.0
    # the delivery classifies conductors and earth wires (class 14); False: they come as class 1, as
    # from providers that classify no wires
    wire_class: bool = True
    # hard negatives (per km²)
    cranes: float = 0.4
    telecom_masts: float = 0.6
    cranes_beside_lines: int = 0  # per block, each beside a line tower (towerpipe.synth.negatives)
    wind_turbines: float = 0.3
    chimneys: float = 0.4
    poles_along_roads: float = 0.6  # probability that a road carries poles
    pole_spacing: tuple[float, float] = (30.0, 60.0)
    # noise (per million points)
    noise_low: float = 20.0
    noise_high: float = 15.0
    noise_high_max: float = 1000.0
    # sensor
    flight_height: float = 900.0  # above mean terrain
    half_fov_deg: float = 20.0
    strip_overlap: float = 0.3
    scan_rate_hz: float = 70.0
    aircraft_speed: float = 60.0
    heading_deg: float | None = None  # None: random per zone
    pulse_jitter: float = 0.05
    vertical_factor: float = 0.25  # exposure of vertical surfaces vs horizontal
    member_beam: float = 0.12  # effective extra width of thin members (beam)
    wire_width: float = 0.12  # effective width of a wire seen by the beam
    tower_visibility_min: float = 0.3  # visibility at the base of a tower (occlusion)
    # how a colourised flight sees a tower, drawn per tower: the share of its points that take
    # the tower's own colour (the rest take the orthophoto pixel below: ground, grass, shadow),
    # and a factor on its intensity (reflectance of paint, rust and wet steel varies)
    tower_own_color: tuple[float, float] = (0.6, 0.6)
    tower_intensity: tuple[float, float] = (1.0, 1.0)
    # real tower shapes: relative jitter of their plan scale (each axis) and height
    real_tower_jitter: float = 0.0
    gps_time: bool = True
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """Return the parameters as a JSON-friendly dict."""
        d = dataclasses.asdict(self)
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SceneParams:
        """Rebuild parameters from :meth:`to_dict` output."""
        names = {f.name: f for f in dataclasses.fields(cls)}
        kw = {}
        for k, v in d.items():
            if k not in names:
                continue
            kw[k] = tuple(v) if isinstance(v, list) else v
        return cls(**kw)


_PRESETS: dict[str, dict[str, Any]] = {
    "catalonia": {},
    "flat": dict(
        base_elevation=(5.0, 150.0), max_slope_deg=4.0, forest_cover=0.2, villages=1.2, roads=2.5, wind_turbines=0.5
    ),
    "mountain": dict(
        base_elevation=(700.0, 1800.0),
        max_slope_deg=35.0,
        forest_cover=0.6,
        forest_height=(6.0, 20.0),
        tall_tree_share=0.3,
        villages=0.2,
        scattered_buildings=2.0,
        wind_turbines=0.6,
        telecom_masts=1.0,
    ),
    "urban": dict(
        base_elevation=(5.0, 300.0),
        max_slope_deg=8.0,
        forest_cover=0.1,
        villages=4.0,
        village_buildings=(30, 80),
        tall_building_share=0.2,
        building_height=(4.0, 20.0),
        cranes=2.0,
        chimneys=1.5,
        roads=5.0,
        poles_along_roads=0.9,
    ),
    # small, busy: for tests (every object kind appears on 0.05 km²)
    "test": dict(
        lines_per_km2=12.0,
        min_lines=2,
        villages=15.0,
        village_buildings=(4, 8),
        cranes=60.0,
        telecom_masts=60.0,
        wind_turbines=30.0,
        chimneys=60.0,
        isolated_tall_trees=100.0,
        roads=25.0,
        span=(120.0, 220.0),
        parallel_line_share=0.5,
    ),
}


#: Tower variety aimed at real flights (``tower_variety: true`` of a generated zone): every
#: design, towers coloured mostly by the orthophoto pixel below them, intensity drawn per
#: tower, real shapes with their proportions varied.
TOWER_VARIETY: dict[str, Any] = dict(
    designs=(
        "lattice_waist",
        "double_circuit",
        "small_lattice",
        "monopole",
        "donau",
        "einebenen",
        "tonne",
        "delta",
        "portal",
        "wooden_hframe",
    ),
    design_weights=(0.12, 0.12, 0.1, 0.08, 0.12, 0.1, 0.1, 0.1, 0.08, 0.08),
    tower_own_color=(0.0, 0.5),
    tower_intensity=(0.4, 2.5),
    real_tower_jitter=0.15,
)


def preset_names() -> list[str]:
    """Names accepted by :func:`preset`."""
    return sorted(_PRESETS)


def preset(name: str = "catalonia", **overrides: Any) -> SceneParams:
    """Return the named preset, with optional field overrides.

    Raises
    ------
    ConfigError
        Unknown preset or field name.
    """
    if name not in _PRESETS:
        raise ConfigError(f"synth preset {name!r} unknown; choose one of {preset_names()}")
    return with_overrides(SceneParams(**_PRESETS[name]), **overrides)


def with_overrides(params: SceneParams, **overrides: Any) -> SceneParams:
    """Return ``params`` with some fields replaced (names are checked)."""
    names = {f.name for f in dataclasses.fields(SceneParams)}
    bad = sorted(set(overrides) - names)
    if bad:
        raise ConfigError(f"synth parameter(s) {bad} unknown")
    return dataclasses.replace(params, **overrides)
