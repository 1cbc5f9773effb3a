"""The configuration: loading, validating against the schema, one line per problem; ``towerpipe config``.

The schema holds every default; :func:`validate_config` fills them in (as Snakemake's
``validate(..., set_default=True)`` does) and reports each problem on a line of its own,
naming the key and, for an unknown key, the closest valid one::

    config: infrence: unknown key; did you mean 'inference'?
    config: inference.gate: 1.5 is greater than the maximum of 1

The Snakefile calls :func:`validate_or_exit`, so a bad config stops ``snakemake`` with
those lines only (no traceback, no schema dump). The schema
(``workflow/schemas/config.schema.yaml``) is the only place of the defaults: ``config/config.yaml``
holds the zones and comments; ``towerpipe config`` prints the effective configuration.
"""

from __future__ import annotations

import copy
import difflib
import os
import sys
from collections.abc import Iterable, Mapping, MutableMapping, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, ClassVar, Self

import yaml

from towerpipe.errors import ConfigError

#: The shipped configuration and its schema, relative to the repository root.
CONFIG_FILE = "config/config.yaml"
SCHEMA_FILE = "workflow/schemas/config.schema.yaml"
#: The config files the Snakefile loads (``configfile:``), in order.
WORKFLOW_CONFIG_FILES = (CONFIG_FILE, "config/models.yaml")

#: Longest message of one problem (a value printed in full could be a whole section).
MAX_PROBLEM_CHARS = 240


#: PyYAML's safe loader, libyaml's where PyYAML has it: the same documents in a tenth of the time
#: (the schema, read at every Snakemake start and every command: 0.030 → 0.003 s).
_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def load_yaml(path: str | os.PathLike[str], what: str = "config file") -> dict[str, Any]:
    """A YAML mapping from a file; a missing or malformed file is a one-line :class:`ConfigError`."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{what} {p}: no such file")
    try:
        data = yaml.load(p.read_text(encoding="utf-8"), Loader=_SAFE_LOADER)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(f"{what} {p}: not valid YAML{where}: {problem}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{what} {p}: must be a mapping of keys to values, not {type(data).__name__}")
    return data


def update_config(base: MutableMapping[str, Any], overrides: Mapping[str, Any]) -> MutableMapping[str, Any]:
    """Merge ``overrides`` into ``base`` recursively, as Snakemake merges ``--configfile`` files."""
    for k, v in overrides.items():
        if isinstance(v, Mapping) and isinstance(base.get(k), MutableMapping):
            update_config(base[k], v)
        else:
            base[k] = copy.deepcopy(v)
    return base


def load_config(
    configfiles: Sequence[str | os.PathLike[str]] = (),
    *,
    root: str | os.PathLike[str] = ".",
    schema: str | os.PathLike[str] | None = None,
) -> dict[str, Any]:
    """The shipped config with ``configfiles`` merged over it, validated, defaults filled in."""
    root = Path(root)
    config = load_yaml(root / CONFIG_FILE)
    for f in configfiles:
        update_config(config, load_yaml(f))
    return validate_config(config, schema or root / SCHEMA_FILE)


def _validator_class() -> Any:
    """A draft 2020-12 validator that fills in the schema's defaults while it validates."""
    from jsonschema import Draft202012Validator, validators

    check_properties = Draft202012Validator.VALIDATORS["properties"]

    def properties_with_defaults(validator: Any, properties: Mapping[str, Any], instance: Any, schema: Any):
        if isinstance(instance, dict):
            for name, sub in properties.items():
                if isinstance(sub, Mapping) and "default" in sub:
                    instance.setdefault(name, copy.deepcopy(sub["default"]))
        yield from check_properties(validator, properties, instance, schema)

    return validators.extend(Draft202012Validator, {"properties": properties_with_defaults})


def _key_path(path: Iterable[Any]) -> str:
    return ".".join(str(p) for p in path)


def _closest(key: str, valid: Sequence[str]) -> str:
    close = difflib.get_close_matches(key, list(valid), n=1, cutoff=0.6)
    if close:
        return f"did you mean '{close[0]}'?"
    return f"valid keys: {', '.join(valid)}" if valid else "no keys are allowed here"


def _problems(error: Any) -> list[str]:
    """One line per problem of a jsonschema error (an unknown key each on its own line)."""
    where = _key_path(error.absolute_path)
    if error.validator == "additionalProperties" and isinstance(error.instance, Mapping):
        props = list((error.schema.get("properties") or {}).keys())
        patterns = list((error.schema.get("patternProperties") or {}).keys())
        import re

        extra = [k for k in error.instance if k not in props and not any(re.search(p, str(k)) for p in patterns)]
        return [f"{_key_path([*error.absolute_path, k])}: unknown key; {_closest(str(k), props)}" for k in extra]
    message = " ".join(error.message.split())
    if error.validator == "format" and error.validator_value == "crs":
        cause = " ".join(str(error.cause or "").split())
        message = f'{error.instance!r} is not a CRS ({cause}); write it as e.g. "EPSG:25831"'
    if len(message) > MAX_PROBLEM_CHARS:
        message = message[: MAX_PROBLEM_CHARS - 1] + "…"
    return [f"{where or '(top level)'}: {message}"]


def _is_crs(value: Any) -> bool:
    """A string pyproj reads as a CRS (``EPSG:25831``, WKT, PROJ); raises pyproj's ``CRSError`` (a
    ``RuntimeError``)."""
    if not isinstance(value, str):
        return True
    from pyproj import CRS  # only for a config that names a CRS: 0.13 s of import

    return bool(CRS.from_user_input(value))


def _format_checker() -> Any:
    """The schema's formats: ``crs`` (:func:`_is_crs`)."""
    from jsonschema import FormatChecker

    checker = FormatChecker(())
    checker.checks("crs", raises=RuntimeError)(_is_crs)
    return checker


def config_problems(config: MutableMapping[str, Any], schema: Mapping[str, Any]) -> list[str]:
    """Every problem of ``config`` against ``schema``, one line each (defaults are filled in)."""
    validator = _validator_class()(schema, format_checker=_format_checker())
    lines: list[str] = []
    for error in sorted(validator.iter_errors(config), key=lambda e: [str(p) for p in e.absolute_path]):
        for line in _problems(error):
            if line not in lines:
                lines.append(line)
    return lines


def validate_config(
    config: MutableMapping[str, Any], schema: str | os.PathLike[str] | Mapping[str, Any]
) -> MutableMapping[str, Any]:
    """Validate ``config`` in place (defaults filled in) and return it.

    Raises
    ------
    ConfigError
        With one line per problem, each ``key.path: what is wrong``.
    """
    schema = load_yaml(schema, "schema") if isinstance(schema, (str, os.PathLike)) else schema
    problems = config_problems(config, schema)
    if problems:
        raise ConfigError("\n".join(f"config: {p}" for p in problems))
    return config


def exit_with(message: str) -> None:
    """Stop with status 1 printing ``config: <message>`` only.

    For configuration errors found while Snakemake builds the DAG (a zone that is not
    configured, an input directory that does not exist): raised as an exception, they
    would come with Snakemake's traceback of the input function.
    """
    print(message if message.startswith("config: ") else f"config: {message}", file=sys.stderr, flush=True)
    raise SystemExit(1)


def repo_root(start: str | os.PathLike[str] | None = None) -> Path:
    """The towerpipe checkout: ``start`` (the working directory) when it holds the schema, else
    the checkout this package was installed from (editable install)."""
    for cand in (Path(start or os.getcwd()), Path(__file__).resolve().parents[2]):
        if (cand / SCHEMA_FILE).is_file():
            return cand
    raise ConfigError(f"no {SCHEMA_FILE} here: run in the towerpipe directory")


def effective_config(
    configfiles: Sequence[str | os.PathLike[str]] = (), *, root: str | os.PathLike[str] | None = None
) -> dict[str, Any]:
    """What the workflow runs with: :data:`WORKFLOW_CONFIG_FILES`, then ``configfiles`` merged
    over them (as ``snakemake --configfile``), validated, every default filled in."""
    root = repo_root(root)
    config: dict[str, Any] = {}
    for f in [*(root / f for f in WORKFLOW_CONFIG_FILES), *configfiles]:
        update_config(config, load_yaml(f))
    return validate_config(config, root / SCHEMA_FILE)


def _config_cmd(args: Any) -> int:
    config = effective_config(args.configfiles)
    sys.stdout.write(yaml.safe_dump(config, sort_keys=False, allow_unicode=True, width=100))
    return 0


def register(subparsers: Any) -> None:
    """Add ``towerpipe config``."""
    p = subparsers.add_parser(
        "config",
        help="print the effective configuration (schema defaults filled in) as YAML",
        description="Print the configuration the workflow runs with, as YAML: config/config.yaml and "
        "config/models.yaml, the FILEs merged over them (as `snakemake --configfile FILE`), "
        f"and every default of {SCHEMA_FILE} filled in.",
    )
    p.add_argument("configfiles", nargs="*", metavar="FILE", help="YAML merged over the shipped config (your zones)")
    p.set_defaults(func=_config_cmd)


def validate_or_exit(config: MutableMapping[str, Any], schema: str | os.PathLike[str]) -> None:
    """:func:`validate_config`, or exit with status 1 printing only the problems (for the Snakefile)."""
    try:
        validate_config(config, schema)
    except ConfigError as exc:
        exit_with(str(exc))


class Section:
    """A typed section of the validated config: the fields of a frozen dataclass, read by name.

    No defaults in a section: the schema holds them; :meth:`from_config` reads a validated
    config (:func:`validate_config`), which has every key.
    """

    #: The config section the fields come from.
    SECTION: ClassVar[str] = ""

    @classmethod
    def from_config(cls, config: Mapping[str, Any]) -> Self:
        """The section :attr:`SECTION` of a validated config as this type."""
        section = config[cls.SECTION]
        return cls(**{f.name: section[f.name] for f in fields(cls)})


@dataclass(frozen=True)
class TowersConfig(Section):
    """The tower rules of :func:`towerpipe.towers.extract.extract_towers`: the keys of the
    ``towers`` section it uses (``wire_line_coverage`` is the conductor context's).

    No defaults here: the schema holds them; :meth:`from_config` reads a validated config.
    """

    SECTION: ClassVar[str] = "towers"

    #: Towers are clustered from the points whose single-view probability reaches this.
    threshold: float
    #: Points closer than this (m, 3-D) belong to one tower.
    linkage: float
    #: A cluster standing on the masts of towers whose tops stand this far (m) over the saddle
    #: between them is split into one tower each (0: never; :mod:`towerpipe.towers.masts`).
    mast_prominence: float
    #: Rule 23: an accepted cluster whose lower peak stands this share of its height over the saddle
    #: to a higher one, over a body of its own, is parted and each part judged (0: never;
    #: :mod:`towerpipe.towers.peaks`).
    peak_share: float
    #: Towers with fewer points are dropped.
    min_points: int
    #: Towers lower than this (m, max HAG) are dropped.
    min_height: float
    #: Towers whose 90th percentile of point probabilities is lower are dropped.
    min_core_prob: float
    #: Rule 21: the core probability a cluster at least ``wire_min_height`` high needs instead
    #: (``None``: ``min_core_prob``); the conductor rule and the shape check judge it next.
    tall_core_prob: float | None
    #: Towers at least ``wire_min_height`` high with a lower conductor support are dropped.
    min_wire_support: float
    #: The conductor rule applies to towers at least this high (m).
    wire_min_height: float
    #: Towers whose lowest point is above this share of their height are dropped.
    max_base_ratio: float
    #: The shape verifier: ``shipped``, ``none`` or a directory (:mod:`towerpipe.towers.shape`).
    verifier: str
    #: Towers whose shape score is lower are dropped (0 keeps all).
    min_shape_score: float
    #: The object of a tile denser than this (points a square metre) is thinned to it before the
    #: verifier scores it (``None``: never; :func:`towerpipe.towers.shape_check.verifier_view`).
    verifier_density: float | None
    #: Rule 13: the shape score a cluster at least ``wire_min_height`` high needs instead
    #: (``None``: ``min_shape_score``); the conductor rule judges it next.
    tall_shape_score: float | None
    #: A cluster the shape check drops is clustered again from its points at or above each
    #: of these probabilities in turn, and each part is judged (empty: never).
    split_thresholds: Sequence[float]
    #: A split's parts with fewer points (at least ``min_points``) are not clusters: a part cut from a
    #: crown at a higher probability is mostly its top.
    min_split_points: int
    #: Rule 9's last step: a dropped cluster that no split threshold parts is linked again from its own
    #: points at this linkage (m, 3-D) and each part is judged (0: never).
    split_linkage: float
    #: Rule 12: a cluster the shape check drops and no split replaces is kept when the conductors
    #: pointing at it lie at least this far (m, median) below its top (0: never).
    vouch_height: float
    #: Rule 12 for a cluster whose shape score is at least ``vouch_low_score``: the conductors need only
    #: lie this far (m, median) below its top (0: never).
    vouch_low_height: float
    #: The shape score a cluster needs for ``vouch_low_height`` to apply to it.
    vouch_low_score: float
    #: Rule 14: a cluster whose shape is in doubt (kept by rule 12 or 13, no shape score, or a
    #: rescue's) that the conductor rule judges (or rule 12 keeps) is dropped when the conductors
    #: pointing at it lie more unevenly than this on the two sides of its base (0: never;
    #: :func:`towerpipe.towers.conductor_rules.conductor_balance`).
    min_conductor_balance: float
    #: Rule 15: a cluster at least ``wire_min_height`` high whose narrow plan reaches this far (m)
    #: from its base on one side is dropped, a crane's jib (0: never; :mod:`towerpipe.towers.plan`).
    max_arm_reach: float
    #: Rule 16: a cluster whose points over every 1 m plan cell lie within this height range (m) is
    #: dropped, a piece of conductor (0: never; :func:`towerpipe.towers.plan.tallest_stand`).
    min_stand: float
    #: Rule 17: a cluster more than this share of whose points lie on the lines of the conductors the
    #: wire detector finds around it is dropped, a piece of conductor (1: never;
    #: :func:`towerpipe.towers.conductor_rules.line_share`).
    max_line_share: float
    #: Rule 18: a cluster that passes the shape check is judged again without the points of its object
    #: on those conductors' lines, and dropped below this score (0: never;
    #: :func:`towerpipe.towers.conductor_rules.bare_score`).
    min_bare_score: float
    #: Rule 19: where the conductor support is unknown, or under ``min_wire_support`` for a tall cluster,
    #: the conductors within 80 m decide: dropped (unknown support) or kept (low support) by whether their
    #: balance reaches this (0: never, rule 8 alone; :func:`towerpipe.towers.conductor_rules.near_balance`).
    min_near_balance: float
    #: Rule 20: a cluster with at least this many conductor points pointing at it over its top, and
    #: fewer at or below it, is dropped, a crown under a line (0: never;
    #: :func:`towerpipe.towers.conductor_rules.under_line`).
    under_line: int
    #: Rule 22: a cluster lower than ``max_height`` m near whose base fewer than ``conductors`` conductor
    #: points hang (rule 20's count), standing less than ``clearance`` m over what stands around it, is
    #: dropped, a crown (``conductors`` 0: never; :func:`towerpipe.towers.conductor_rules.canopy_clearance`).
    canopy: Mapping[str, float | int]
    #: Rule 10: clusters no accepted tower holds, from the points at or above this
    #: probability, are judged again (0: never; see :func:`towerpipe.towers.extract.extract_towers`).
    rescue_threshold: float
    #: The points of a tower's foot that are reported (``height``, ``band``, ``inside``,
    #: ``outside``, ``outline_points``; :func:`towerpipe.towers.foot.foot_mask`).
    foot: Mapping[str, float | int]
    #: The faint points of a tower's body that are reported (``threshold``, ``outside``,
    #: ``min_height``; :func:`towerpipe.towers.column.column_mask`).
    column: Mapping[str, float]
    #: The lower points of a tower that stand out from the tower above them, crowns beside it, are
    #: not reported (``beyond``, ``height``, ``below``, ``outline_points``;
    #: :func:`towerpipe.towers.crown.crown_mask`).
    crowns: Mapping[str, float | int]

    def core_needed(self, height: float) -> float:
        """The core probability a cluster whose highest point stands ``height`` m above the ground
        needs (rule 4, and rule 21 for a tall one)."""
        if self.tall_core_prob is not None and height >= self.wire_min_height:
            return min(self.min_core_prob, self.tall_core_prob)
        return self.min_core_prob


@dataclass(frozen=True)
class InferenceConfig(Section):
    """The settings of :func:`towerpipe.inference.infer.predict_tile`: the keys of the
    ``inference`` section it uses (``model`` picks the bundle, ``threshold`` applies after
    the windows: neither is here).

    No defaults here: the schema holds them; :meth:`from_config` reads a validated config.
    """

    SECTION: ClassVar[str] = "inference"

    #: Window side (m).
    window: float
    #: Step of the sliding windows (m) with ``windows: grid``; ``window - stride`` is the overlap.
    stride: float
    #: ``"candidates"`` (one window centred on each height peak) or ``"grid"`` (sliding windows).
    windows: str
    #: Windows whose classifier probability is below this are background.
    gate: float
    #: With the shape gate's scores, a window the classifier scores at least ``gate`` but under
    #: this is segmented only if its peak object scores at least ``unsure_shape``
    #: (:func:`towerpipe.inference.windows.classifier_pass`).
    gate_sure: float
    #: The shape score a window under ``gate_sure`` needs to be segmented (0: no condition).
    unsure_shape: float
    #: ``"max"`` or ``"mean"`` over the segmented windows holding a point.
    combine: str
    #: Windows per classifier call.
    batch_size: int
    #: Windows with fewer model-input points are empty.
    min_points: int
    #: Windows whose highest point is lower (m HAG) are background without a classifier pass
    #: (``None``: every window is classified); the floor of the candidate peaks.
    min_height: float | None
    #: Views of each segmented window averaged (1, 2, 4 or 8).
    tta: int
    #: With candidate windows, windows whose peak object the shape verifier
    #: (``towers.verifier``) scores below this are background without a classifier pass (0: none).
    shape_gate: float
    #: With candidate windows, a window whose peak object ``towers.verifier`` scores at least this passes
    #: the classifier's gate whatever the classifier says (``None``: never).
    shape_pass: float | None
    #: With candidate windows, the peaks within this radius (m) that are not peaks within
    #: :data:`~towerpipe.inference.candidates.PEAK_RADIUS` also get a window (0: none).
    secondary_radius: float
    #: A secondary peak's window sets the probabilities of the points within this distance (m) of its centre only.
    secondary_reach: float
    #: With candidate windows, the columns (:func:`~towerpipe.inference.candidates.stem_columns`) farther
    #: than this (m) from every peak also get a window, segmented only beside a tower the peak windows
    #: painted (:func:`~towerpipe.inference.candidates.stems_beside`; 0: none).
    stem_gap: float
    #: A stem candidate's window sets the probabilities of the points within this distance (m) of its centre only.
    stem_reach: float


@dataclass(frozen=True)
class PreprocessConfig(Section):
    """The parameters of the preprocessing (:mod:`towerpipe.preprocess.split`,
    :mod:`towerpipe.preprocess.tile`): the ``preprocess`` section.

    No defaults here: the schema holds them; :meth:`from_config` reads a validated config.
    """

    SECTION: ClassVar[str] = "preprocess"

    #: Side of a tile (m).
    tile_size: float
    #: Buffer around a tile core (m; at least one window).
    buffer: float
    #: DTM cell size (m).
    dtm_resolution: float
    #: Points higher above ground are noise (paper: 100 m).
    hag_max: float
    #: Points lower than this below the DTM are noise (low outliers).
    hag_min: float
    #: Below this share of class-2 points, ground is classified with PDAL.
    min_ground_fraction: float
    #: ``"smrf"`` or ``"csf"``.
    ground_filter: str
    #: Input classes that are noise in the delivery besides :data:`towerpipe.classes.NOISE` (left out
    #: of the processing with them and the withheld points).
    extra_noise_classes: list[int]
    #: Run PDAL's statistical outlier filter (slow: superlinear in PDAL 2.2).
    outlier: bool
    #: Neighbours of the outlier filter.
    outlier_mean_k: int
    #: Standard deviations beyond which the outlier filter drops a point.
    outlier_multiplier: float
