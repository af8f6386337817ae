"""Dataset spec files (YAML or JSON): parsing and validation.

A spec names one scene and how its parameters vary over the items of the
dataset. Every key is documented in ``docs/dataset.md``; in short::

    name: cbox-depths              # optional, informational
    description: ...               # optional, informational
    scene: cornell_box             # shipped scene name, or a path (relative to the spec file)
    seed: 0                        # master seed (items derive theirs from it)
    spp: 4                         # samples per pixel (0: the scene's own value)
    variant: llvm_ad_mono          # optional Mitsuba variant
    repeats: 2                     # items per grid point, each with its own seed and draws
    defines: {width: 8, height: 8} # fixed -D values
    grid:                          # cartesian product of the listed values
      max_depth: [2, 4]
    random:                        # seeded draws, one per item
      t0_ps: {uniform: [9000, 11000], round: 1}
    object:                        # optional generated mesh, passed as -D <define>=mesh.ply
      kind: mannequin
      define: mesh
      pose: arms_down
    detector:                      # optional: turn each ideal capture into counts
      pulses: 100000
      pde: 0.7
    noise_target: 0.1              # optional (needs detector): render each item to this rendering/photon ratio

Parameter names in ``grid`` and ``random``: ``spp``, ``object.<name>``,
``detector.<name>``, and anything else is a scene ``-D`` parameter (also
written ``define.<name>``). A string value ``"${name}"`` takes the value of
another parameter of the same item (e.g. ``distance: "${object.position_z}"``).

Everything here is checked without rendering; :mod:`transient_mi.dataset.runner`
also loads the scene once before any work.
"""

from __future__ import annotations

import json
import math
import numbers
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from transient_core.errors import UserInputError

from .distributions import Distribution
from .objects import OBJECT_KINDS

#: Top-level keys of a spec and what they hold.
TOP_KEYS: dict[str, str] = {
    "name": "informational name",
    "description": "informational text",
    "scene": "shipped scene name or XML path (required)",
    "seed": "master seed, integer in [0, 2**32)",
    "spp": "samples per pixel, integer >= 1 (0: the scene's value)",
    "variant": "Mitsuba variant",
    "repeats": "items per grid point, integer >= 1",
    "defines": "fixed scene -D values",
    "grid": "parameters -> lists of values (cartesian product)",
    "random": "parameters -> distributions (seeded draws)",
    "object": "generated mesh: kind, define, fixed parameters",
    "detector": "detector settings (enables counts)",
    "noise_target": "largest rendering / photon variance ratio at the item's budget, number > 0 (needs detector)",
}
#: Detector settings that are arguments of ``detect_stack`` rather than ``DetectorParams`` fields.
DETECT_ARGS = ("pulses", "exposure_s", "engine")
#: Engines of ``detect_stack`` (``engine=``).
DETECTOR_ENGINES = ("auto", "analytic", "exact")
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_REF = re.compile(r"^\$\{([A-Za-z_][A-Za-z0-9_.]*)\}$")


def detector_param_names() -> list[str] | None:
    """Names of the detector's parameters, or None when :mod:`spad_detector` is not installed."""
    try:
        from spad_detector import DetectorParams  # noqa: F401  (lazy: optional part)
        from spad_detector import detect_stack  # noqa: F401
    except ImportError:
        return None
    import dataclasses

    return [f.name for f in dataclasses.fields(DetectorParams)]


def is_reference(v: Any) -> str | None:
    """The parameter a ``"${name}"`` value refers to, else None."""
    if isinstance(v, str):
        m = _REF.match(v.strip())
        if m:
            return m.group(1)
    return None


def _is_int(v: Any) -> bool:
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


def check_value(where: str, v: Any) -> Any:
    """A parameter value: number, string, boolean or list of numbers (for vectors)."""
    if isinstance(v, bool) or isinstance(v, str) or _is_int(v):
        return v
    if isinstance(v, numbers.Real):
        if not math.isfinite(float(v)):
            raise UserInputError(f"{where}: {v!r} is not a finite number")
        return float(v)
    if isinstance(v, (list, tuple)) and v and all(isinstance(x, numbers.Real) and not isinstance(x, bool)
                                                  for x in v):
        return [int(x) if _is_int(x) else float(x) for x in v]
    raise UserInputError(f"{where}: {v!r} is not a parameter value (number, string, boolean or list of numbers)")


@dataclass
class DatasetSpec:
    """A parsed, validated spec (see the module docstring).

    Parameter keys are canonical: ``spp``, ``define.<name>``,
    ``object.<name>``, ``detector.<name>``.
    """

    scene: str
    scene_file: Path
    seed: int = 0
    spp: int = 0
    variant: str | None = None
    repeats: int = 1
    defines: dict[str, Any] = field(default_factory=dict)
    grid: dict[str, list] = field(default_factory=dict)
    random: dict[str, Distribution] = field(default_factory=dict)
    object_kind: str | None = None
    object_define: str | None = "mesh"
    object_params: dict[str, Any] = field(default_factory=dict)
    detector: dict[str, Any] | None = None
    #: Largest ratio of rendering to photon variance at each item's detector budget (``render --noise-target``);
    #: None: render the item's spp (or the quadrature's settings) as they are.
    noise_target: float | None = None
    name: str | None = None
    description: str | None = None
    spec_file: Path | None = None

    @property
    def has_detector(self) -> bool:
        """Whether items get a counts capture."""
        return self.detector is not None

    @property
    def n_grid_points(self) -> int:
        n = 1
        for v in self.grid.values():
            n *= len(v)
        return n

    @property
    def n_items(self) -> int:
        return self.repeats * self.n_grid_points

    def fixed_values(self) -> dict[str, Any]:
        """Canonical key -> value for everything not varied by grid or random."""
        out: dict[str, Any] = {"spp": self.spp}
        out.update({f"define.{k}": v for k, v in self.defines.items()})
        out.update({f"object.{k}": v for k, v in self.object_params.items()})
        out.update({f"detector.{k}": v for k, v in (self.detector or {}).items()})
        return out

    def varied_keys(self) -> list[str]:
        return list(self.grid) + list(self.random)

    def to_dict(self) -> dict:
        """The normalised spec (what ``dataset.json`` records)."""
        d: dict[str, Any] = {
            "name": self.name, "description": self.description, "scene": self.scene, "seed": self.seed,
            "spp": self.spp, "variant": self.variant, "repeats": self.repeats, "defines": dict(self.defines),
            "grid": {k: list(v) for k, v in self.grid.items()},
            "random": {k: v.to_spec() for k, v in self.random.items()},
            "object": None if self.object_kind is None else
            {"kind": self.object_kind, "define": self.object_define, **self.object_params},
            "detector": None if self.detector is None else dict(self.detector),
        }
        if self.noise_target is not None:  # only when set: dataset.json of a spec without it is unchanged
            d["noise_target"] = self.noise_target
        return d


# ----------------------------------------------------------------------------- loading


def read_spec_file(path: str | Path) -> dict:
    """Read a YAML or JSON spec file into a mapping.

    Raises
    ------
    UserInputError
        Missing file, unreadable file, invalid YAML/JSON, or not a mapping.
    """
    p = Path(path)
    if not p.exists():
        raise UserInputError(f"spec file {str(p)!r} does not exist")
    if not p.is_file():
        raise UserInputError(f"spec file {str(p)!r} is not a file")
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise UserInputError(f"spec file {str(p)!r} cannot be read ({e})") from None
    if p.suffix.lower() == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as e:
            raise UserInputError(f"spec file {p}: not valid JSON ({e})") from None
    else:
        import yaml

        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as e:
            msg = " ".join(str(e).split())
            raise UserInputError(f"spec file {p}: not valid YAML ({msg})") from None
    if not isinstance(data, dict):
        raise UserInputError(f"spec file {p}: expected a mapping of keys ({', '.join(TOP_KEYS)}), "
                             f"got {type(data).__name__}")
    return data


def resolve_scene(scene: Any, base_dir: Path) -> Path:
    """Path of the spec's scene: a file (relative to the spec's folder) or a shipped scene name."""
    if not isinstance(scene, str) or not scene.strip():
        raise UserInputError(f"scene: {scene!r}; give a shipped scene name (e.g. cornell_box) or an XML file path")
    p = Path(scene).expanduser()
    cand = p if p.is_absolute() else base_dir / p
    if cand.is_file():
        return cand.resolve()
    from transient_mi.scenes import SCENES_DIR

    if "/" not in scene and (SCENES_DIR / (scene if scene.endswith(".xml") else f"{scene}.xml")).is_file():
        from transient_mi.scenes import scene_path

        return scene_path(scene)
    avail = ", ".join(sorted(q.stem for q in SCENES_DIR.glob("*.xml")))
    raise UserInputError(f"scene: {scene!r} is neither a file ({cand} does not exist) nor a shipped scene "
                         f"(available: {avail})")


def _int(where: str, v: Any, lo: int, hi: int | None = None) -> int:
    if not _is_int(v) or v < lo or (hi is not None and v >= hi):
        rng = f">= {lo}" if hi is None else f"in [{lo}, {hi})"
        raise UserInputError(f"{where}: {v!r}; expected an integer {rng}")
    return int(v)


def _mapping(where: str, v: Any) -> dict:
    if v is None:
        return {}
    if not isinstance(v, dict):
        raise UserInputError(f"{where}: expected a mapping of name: value, got {v!r}")
    return v


def parse_spec(data: dict, *, spec_file: str | Path | None = None) -> DatasetSpec:
    """Validate a spec mapping (as read from YAML/JSON) into a :class:`DatasetSpec`.

    Raises
    ------
    UserInputError
        Naming the key, the value and what is allowed: unknown keys, unknown
        parameters (of the object or detector; scene parameters are checked
        against the scene by the runner), empty lists or ranges, bad
        distributions, a parameter given twice, an unknown scene.
    """
    unknown = [k for k in data if k not in TOP_KEYS]
    if unknown:
        raise UserInputError(f"unknown key {unknown[0]!r} in the spec; allowed: {', '.join(TOP_KEYS)}")
    if "scene" not in data:
        raise UserInputError("the spec has no 'scene' (a shipped scene name such as cornell_box, or an XML path)")
    base = Path(spec_file).resolve().parent if spec_file is not None else Path.cwd()
    for k in ("name", "description", "variant"):
        if data.get(k) is not None and not isinstance(data[k], str):
            raise UserInputError(f"{k}: {data[k]!r}; expected a string")
    spec = DatasetSpec(
        scene=data["scene"],
        scene_file=resolve_scene(data["scene"], base),
        seed=_int("seed", data.get("seed", 0), 0, 2**32),
        spp=_int("spp", data.get("spp", 0), 0),
        variant=data.get("variant"),
        repeats=_int("repeats", data.get("repeats", 1), 1),
        name=data.get("name"),
        description=data.get("description"),
        spec_file=Path(spec_file).resolve() if spec_file is not None else None,
    )
    if spec.variant is not None:
        from transient_mi.variant import check_variant

        check_variant(spec.variant)

    # fixed scene defines
    for k, v in _mapping("defines", data.get("defines")).items():
        if not isinstance(k, str) or not _NAME.match(k):
            raise UserInputError(f"defines: {k!r} is not a valid parameter name (letters, digits, _)")
        spec.defines[k] = check_value(f"defines.{k}", v)

    # object generator
    obj = data.get("object")
    if obj is not None:
        obj = _mapping("object", obj)
        kind = obj.get("kind")
        if kind not in OBJECT_KINDS:
            raise UserInputError(f"object.kind: {kind!r}; allowed: {', '.join(OBJECT_KINDS)}")
        spec.object_kind = kind
        define = obj.get("define", "mesh")
        # define: null -> the mesh is written as ground truth only (the scene builds the same object
        # itself, e.g. the `mannequin` shape of scenes/paper_mannequin.xml from its own parameters)
        if define is not None and (not isinstance(define, str) or not _NAME.match(define)):
            raise UserInputError(f"object.define: {define!r} is not a valid scene parameter name (or null)")
        if define is not None and define in spec.defines:
            raise UserInputError(f"object.define: {define!r} is also given in defines; the generated mesh "
                                 f"sets -D {define}=mesh.ply itself")
        spec.object_define = define
        allowed = OBJECT_KINDS[kind].params
        for k, v in obj.items():
            if k in ("kind", "define"):
                continue
            if k not in allowed:
                raise UserInputError(f"object.{k}: unknown parameter of a {kind}; allowed: kind, define, "
                                     f"{', '.join(allowed)}")
            spec.object_params[k] = check_value(f"object.{k}", v)

    # detector settings
    det = data.get("detector", None)
    if "detector" in data:
        det = _mapping("detector", det)
        spec.detector = {}
        for k, v in det.items():
            _check_detector_name(f"detector.{k}", k)
            spec.detector[k] = check_value(f"detector.{k}", v) if v is not None else None

    # grid and random
    taken = set(spec.fixed_values())
    if "spp" not in data:  # the default spp (0: the scene's value) may be varied
        taken.discard("spp")
    for section in ("grid", "random"):
        for raw_key, v in _mapping(section, data.get(section)).items():
            where = f"{section}.{raw_key}"
            key = canonical_key(where, raw_key, spec)
            if key in taken:
                raise UserInputError(f"{where}: parameter {key} is given twice (fixed, in grid or in random); "
                                     "give it in one place")
            taken.add(key)
            if section == "grid":
                if not isinstance(v, (list, tuple)):
                    raise UserInputError(f"{where}: {v!r}; expected a list of values")
                if len(v) == 0:
                    raise UserInputError(f"{where}: empty list; give at least one value")
                vals = [check_value(f"{where}[{i}]", x) for i, x in enumerate(v)]
                spec.grid[key] = vals
            else:
                spec.random[key] = Distribution.parse(where, v)
            if key.startswith("detector.") and spec.detector is None:
                spec.detector = {}
    _check_spp_values(spec)
    if "noise_target" in data:
        spec.noise_target = _noise_target(data["noise_target"], spec)
    if spec.has_detector and detector_param_names() is None:
        raise UserInputError("detector: the spec asks for detector settings, but spad_detector is not "
                             "available in this installation; remove the detector settings")
    return spec


def _noise_target(v: Any, spec: DatasetSpec) -> float:
    """The spec's ``noise_target``: a finite number > 0, with a detector section giving the budget."""
    if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(float(v)) or v <= 0:
        raise UserInputError(f"noise_target: {v!r}; expected a finite number > 0 (e.g. 0.1, the noise standard)")
    if not spec.has_detector:
        raise UserInputError(f"noise_target: {v!r} needs a detector section (the photon budget the rendering "
                             "noise is compared with: detector: {exposure_s: ...})")
    return float(v)


def _check_detector_name(where: str, name: Any) -> None:
    names = detector_param_names()
    if names is None:
        raise UserInputError(f"{where}: the spec asks for detector settings, but spad_detector is not "
                             "available in this installation; remove the detector settings")
    if name not in names and name not in DETECT_ARGS:
        raise UserInputError(f"{where}: unknown detector setting {name!r}; allowed: "
                             f"{', '.join(list(DETECT_ARGS) + names)}")


def canonical_key(where: str, key: Any, spec: DatasetSpec) -> str:
    """Canonical form of a grid/random parameter name (checks that it exists where it can be checked)."""
    if not isinstance(key, str):
        raise UserInputError(f"{where}: {key!r} is not a parameter name")
    if key == "spp":
        return "spp"
    if key.startswith("define."):
        name = key[len("define."):]
        if not _NAME.match(name):
            raise UserInputError(f"{where}: {name!r} is not a valid scene parameter name (letters, digits, _)")
        return key
    if key.startswith("object."):
        name = key[len("object."):]
        if spec.object_kind is None:
            raise UserInputError(f"{where}: the spec has no object section (object: {{kind: mannequin, ...}})")
        allowed = OBJECT_KINDS[spec.object_kind].params
        if name not in allowed:
            raise UserInputError(f"{where}: unknown parameter of a {spec.object_kind}; allowed: "
                                 f"{', '.join('object.' + a for a in allowed)}")
        return key
    if key.startswith("detector."):
        _check_detector_name(where, key[len("detector."):])
        return key
    if not _NAME.match(key):
        raise UserInputError(f"{where}: {key!r} is not a parameter name; use spp, object.<name>, "
                             "detector.<name> or a scene parameter (letters, digits, _)")
    if spec.object_define is not None and key == spec.object_define and spec.object_kind is not None:
        raise UserInputError(f"{where}: {key!r} is set by the object generator (object.define)")
    return f"define.{key}"


def _check_spp_values(spec: DatasetSpec) -> None:
    vals = list(spec.grid.get("spp", []))
    if "spp" in spec.random:
        d = spec.random["spp"]
        if d.kind not in ("randint", "choice"):
            raise UserInputError(f"random.spp: {d.kind} draws floats; use randint or choice for samples per pixel")
        vals += d.probe_values()
    for v in vals:
        if not _is_int(v) or v < 1:
            raise UserInputError(f"spp: {v!r}; samples per pixel must be integers >= 1")


def load_spec(path: str | Path) -> DatasetSpec:
    """Read and validate a spec file (YAML, or JSON by the ``.json`` suffix)."""
    return parse_spec(read_spec_file(path), spec_file=path)
