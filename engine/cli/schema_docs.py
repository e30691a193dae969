"""docs/SCENARIOS.md, generated from the pydantic schemas, so the reference cannot drift.

    python -m vitaplace.engine.cli.schema_docs docs/SCENARIOS.md     # regenerate
    python -m vitaplace.engine.cli.schema_docs                       # print

Every schema field documents itself with ``Field(description=...)``, the one way fields are
documented: a table row is the field's type, default, constraints and description as pydantic
holds them, and a field without a description is an error. `tests/layout/test_docs.py` checks the
committed file equals what this module generates.
"""

from __future__ import annotations

import sys
import types
import typing
from pathlib import Path

import pydantic
from pydantic_core import PydanticUndefined

from vitaplace.engine.config.scenario import (
    ComplementarityPair,
    EvaluationPair,
    Fusion,
    Gates,
    Method,
    QueryDropout,
    RecordedRuns,
    ReportSettings,
    Scenario,
    ScoringSettings,
    SequenceSettings,
    TrainingData,
)
from vitaplace.engine.sim.condition import CameraCondition, Condition, Fog, LightCondition, Occlusion
from vitaplace.engine.sim.controllers import (
    ForagingGains,
    ForagingRun,
    OrbitRun,
    RouteRun,
    StationsRun,
    TeleopRun,
    VisitsRun,
)
from vitaplace.engine.sim.environment import (
    ArenaSpec,
    BoardSpec,
    BoxLandmark,
    CylinderLandmark,
    EnvironmentSpec,
    LightingSpec,
    LightSpec,
    MaterialSpec,
    PanelSpec,
    RockLandmark,
    TextureSpec,
    WallSpec,
)
from vitaplace.engine.sim.robot import RobotSpec
from vitaplace.plugins.autoencoder.extractor import AutoencoderParams
from vitaplace.plugins.handcrafted.extractor import HandcraftedParams
from vitaplace.plugins.mupnet.extractor import MupnetParams

#: (heading, model, what it is) in the order the reference presents them
SECTIONS: list[tuple[str, type[pydantic.BaseModel], str]] = [
    ("Scenario", Scenario, "the top level of a scenario file"),
    ("train: TrainingData", TrainingData, "the training run"),
    ("evaluations[]: EvaluationPair", EvaluationPair, "one evaluation environment (two runs, simulated or recorded)"),
    ("evaluations[].datasets: RecordedRuns", RecordedRuns, "an evaluation's two recorded runs (docs/DATA.md)"),
    ("evaluations[].gates: Gates", Gates, "what `vitaplace difficulty` checks an evaluation against"),
    ("evaluations[].query_dropout: QueryDropout", QueryDropout,
     "sensors lost at query time (docs/plugins.md, Missing modalities)"),
    ("run (kind: foraging): ForagingRun", ForagingRun, "a foraging run (training); each kind has only its own keys"),
    ("run.gains: ForagingGains", ForagingGains, "the gains and thresholds of the foraging states"),
    ("run (kind: visits): VisitsRun", VisitsRun,
     "foraging with station-style visits to the tactile landmarks (training); its foraging keys are foraging's"),
    ("run (kind: teleop): TeleopRun", TeleopRun, "an emulated keyboard teleoperator's drive (evaluation)"),
    ("run (kind: stations): StationsRun", StationsRun,
     "the teleoperator whisking the same K tactile stations in every drive (evaluation)"),
    ("run (kind: route): RouteRun", RouteRun, "noisy laps of the environment's route"),
    ("run (kind: orbit): OrbitRun", OrbitRun, "noisy laps of a circle, facing outward"),
    ("run.condition, evaluations[].query_condition, evaluations[].reference_condition: Condition", Condition,
     "the lighting and camera state a simulated run is recorded under (docs/SIMULATION.md, Conditions)"),
    ("condition.light: LightCondition", LightCondition, "how the environment's lights differ"),
    ("condition.camera: CameraCondition", CameraCondition,
     "how each frame is degraded: blur, exposure, noise, occlusion"),
    ("condition.camera.occlusion: Occlusion", Occlusion, "the part of the image blanked"),
    ("condition.fog: Fog", Fog, "fog in the air between the camera and the world (linear, as MuJoCo renders it)"),
    ("robot: RobotSpec", RobotSpec, "the robot, its sensors and the physics"),
    ("methods[]: Method", Method, "a feature extractor to compare"),
    ("methods[].params for plugin mupnet", MupnetParams, "the learned MuPNet features"),
    ("methods[].params for plugin autoencoder", AutoencoderParams, "MuPNet's architecture trained by backprop"),
    ("methods[].params for plugin handcrafted", HandcraftedParams, "the ViTa-SLAM front end"),
    ("scoring: ScoringSettings", ScoringSettings, "how features are scored"),
    ("scoring.sequence: SequenceSettings", SequenceSettings, "sequence matching (SeqSLAM) of the distances"),
    ("fusions[]: Fusion", Fusion, "a late fusion of a vision-only and a touch-only method"),
    ("scoring.complementarity[]: ComplementarityPair", ComplementarityPair, "one pair, named by the scenario"),
    ("report: ReportSettings", ReportSettings, "which figures the report draws"),
    ("Environment file: EnvironmentSpec", EnvironmentSpec, "an environment YAML (scenarios/environments)"),
    ("arena: ArenaSpec", ArenaSpec, "walls and floor"),
    ("arena.walls.<wall>: WallSpec", WallSpec, "one wall's look"),
    ("arena.walls.<wall>.panel: PanelSpec", PanelSpec, "a box on a wall's inner face"),
    ("materials.<name>: MaterialSpec", MaterialSpec, "a render material"),
    ("materials.<name>.texture: TextureSpec", TextureSpec, "a procedural or file texture"),
    ("landmarks[] (type: box): BoxLandmark", BoxLandmark, "a box"),
    ("landmarks[] (type: cylinder): CylinderLandmark", CylinderLandmark, "a cylinder"),
    ("landmarks[] (type: rock): RockLandmark", RockLandmark, "a seeded asymmetric convex rock"),
    ("lighting: LightingSpec", LightingSpec, "lights of the scene"),
    ("lighting.lights[]: LightSpec", LightSpec, "a directional light"),
    ("boards[]: BoardSpec", BoardSpec, "a render-only board"),
]


def _type_name(annotation: typing.Any) -> str:
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if annotation is type(None):
        return "null"
    if origin is typing.Annotated:
        return _type_name(args[0])
    if origin is typing.Literal:
        return " \\| ".join(repr(a) for a in args)
    if origin in (typing.Union, types.UnionType):
        return " \\| ".join(_type_name(a) for a in args)
    if origin is not None:
        name = getattr(origin, "__name__", str(origin))
        return f"{name}[{', '.join(_type_name(a) for a in args)}]" if args else name
    return getattr(annotation, "__name__", str(annotation))


def _default(field: pydantic.fields.FieldInfo) -> str:
    if field.default is PydanticUndefined and field.default_factory is None:
        return "**required**"
    value = field.get_default(call_default_factory=True)  # the factory's value, else the default
    if isinstance(value, pydantic.BaseModel):
        return "(see its section)"
    if isinstance(value, dict) and len(str(value)) > 60:
        return "(built in)"
    return f"`{value!r}`" if value is not None else "`None`"


def _constraints(field: pydantic.fields.FieldInfo) -> str:
    out = []
    for item in field.metadata:
        for attr, sign in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<="), ("min_length", "min length"),
                           ("max_length", "max length"), ("pattern", "pattern")):
            value = getattr(item, attr, None)
            if value is not None:
                out.append(f"{sign} {value}")
    return ", ".join(out)


def _first_line(doc: str | None) -> str:
    return " ".join((doc or "").strip().split("\n\n")[0].split())


def model_table(model: type[pydantic.BaseModel]) -> str:
    """The reference table of ``model``: one row per field, its meaning the field's description."""
    rows = ["| key | type | default | constraints | meaning |", "|---|---|---|---|---|"]
    for name, field in model.model_fields.items():
        if not field.description:
            raise ValueError(f"{model.__name__}.{name}: a schema field needs Field(description=...)")
        meaning = field.description.replace("|", "\\|").replace("\n", " ")
        rows.append(f"| `{name}` | {_type_name(field.annotation)} | {_default(field)} | {_constraints(field)} "
                    f"| {meaning} |")
    return "\n".join(rows)


def markdown() -> str:
    parts = [
        "# Scenario and environment reference",
        "",
        "Generated from the pydantic schemas by `python -m vitaplace.engine.cli.schema_docs docs/SCENARIOS.md`;",
        "`tests/layout/test_docs.py` fails when this file is out of date. Unknown keys are errors everywhere.",
        "Units: metres, seconds, degrees in files (radians inside), colours in [0, 1].",
        "",
        "Beyond each key's own range, `vitaplace validate` checks what needs the arena and the robot",
        "together (`engine/sim/plausibility.py`), each refusal naming its key: a run's `start` and its",
        "`orbit_centre` inside the arena, a `start` (the run's or the environment's) not inside a landmark;",
        "the orbit (`orbit_radius`) and the off-route detour",
        "(`off_route_offset`, when `off_route_fraction` or `query_off_route` is set) keep the robot's",
        "body (radius 0.23 m) inside the walls; `control_hz` at least `robot.whisk_hz`; a `route` or `teleop` run",
        "needs an environment with a route. Infinite or NaN numbers are refused everywhere, method",
        "parameters included, and so is a boolean where a number is expected (`epochs: true` is not 1),",
        "in scenario and environment files alike (`lighting: {ambient: true}` is not full light).",
        "A method parameter read only under some choice of another is refused at any",
        "value but its default beside another choice, which would ignore it: MuPNet's `inference_momentum`",
        "(read by the `nesterov` and `preconditioned` solvers, not `gd`), `weight_momentum` (`weight_optimizer:",
        "momentum`), `adam_beta1`, `adam_beta2`, `adam_eps` (`adam`), `precision_floor` (`precision_weighting:",
        "layer` or `channel`), `eta_y_visual`, `eta_y_tactile`, `eta_y_joint` (the plain latent steps:",
        "`training_inference: plain` or `inference_solver: gd`; the settling solvers step by each layer's curvature",
        "bound), and for MuPNet and the autoencoder `cycle_points` (`tactile_input: cycle`) and",
        "`slope` (`activation: leaky_relu`). With MuPNet's plain latent steps (`training_inference: plain` or",
        "`inference_solver: gd`), `latent_prior` times the largest `eta_y` of the network must stay below 2: each",
        "step multiplies the prior's part of a latent by 1 - eta_y latent_prior, and at -1 or below the steps",
        "diverge. A robot whose servo gains overflow (e.g. `servo_damping_ratio: 1e308`) is refused when its",
        "model is built, before the first step. A scenario whose simulation is estimated to take more than 10 minutes",
        "on one core says so (`validate`, and `run` before it starts; progress lines while it runs).",
        "",
    ]
    for heading, model, what in SECTIONS:
        doc = _first_line(model.__doc__)
        parts += [f"## {heading}", "", f"{what[0].upper()}{what[1:]}." + (f" {doc}" if doc else ""), "",
                  model_table(model), ""]
    return "\n".join(parts)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    text = markdown()
    if args:
        Path(args[0]).write_text(text)
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
