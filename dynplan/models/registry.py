"""The world-model configurations, one entry each: tokenizer, prior, caution, training budgets and weights.

A configuration names everything that makes one learned world model: the VQ-VAE tokenizer's config, the
PixelCNN prior's, the caution of the frames the planner sees, the training budgets its committed weights were
trained with (fields of `dynplan.training.budget.TrainBudget`) and the names of those weights in its weights
folder. Every command, preset and loader looks a configuration up here, so adding one is one `register_world_model`
call (docs/extending.md). `paper` is the paper's (docs/protocol.md §2) and `default` ours, the road's; another
world's configurations are registered by its `World.models` module, imported the first time a configuration of
that world, or one not registered yet, is looked up.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import import_module
from pathlib import Path

from dynplan.models.caution import Caution
from dynplan.models.configs import PIXELCNN_PRESETS, PRESETS, PixelCNNConfig, VQVAEConfig
from dynplan.world import DEFAULT_WORLD, world, world_names

STAGES = ("vqvae", "pixelcnn")


@dataclass(frozen=True)
class WorldModelSpec:
    """One world-model configuration. `weights`: stage → file name in `weights_dir` (absent: no committed weights;
    train them or pass a folder; `weights_dir` None: `dynplan/models/weights/`); `budgets`: stage → TrainBudget
    fields of its training."""

    name: str
    tokenizer: VQVAEConfig
    prior: PixelCNNConfig
    caution: Caution = field(default_factory=Caution)
    budgets: Mapping[str, Mapping] = field(default_factory=dict)
    weights: Mapping[str, str] = field(default_factory=dict)
    description: str = ""
    weights_dir: Path | None = None

    @property
    def world(self) -> str:
        """The world whose frames it models."""
        return self.tokenizer.world

    def __post_init__(self) -> None:
        if self.prior.codebook_size != self.tokenizer.codebook_size:
            raise ValueError(
                f"world model {self.name!r}: the prior's codebook_size {self.prior.codebook_size} is not "
                f"the tokenizer's {self.tokenizer.codebook_size}"
            )
        self.caution.check_fits(self.tokenizer.local, self.name)
        unknown = (set(self.budgets) | set(self.weights)) - set(STAGES)
        if unknown:
            raise ValueError(f"world model {self.name!r}: unknown stages {sorted(unknown)}; stages are {STAGES}")


#: name → configuration.
WORLD_MODELS: dict[str, WorldModelSpec] = {}


def register_world_model(spec: WorldModelSpec, replace: bool = False) -> WorldModelSpec:
    """Add a configuration; an existing name is refused unless `replace`."""
    if spec.name in WORLD_MODELS and not replace:
        raise ValueError(f"world model {spec.name!r} is registered already")
    WORLD_MODELS[spec.name] = spec
    return spec


def _register_models_of(world_name: str) -> None:
    """Import the module of world `world_name` that registers its configurations (`World.models`), if it has one."""
    module = world(world_name).models
    if module is not None:
        import_module(module)


def world_model_names() -> list[str]:
    """Every registered configuration of every world, in the order they were registered."""
    for name in world_names():
        _register_models_of(name)
    return list(WORLD_MODELS)


def world_model_spec(name: str) -> WorldModelSpec:
    """The configuration called `name` (a ValueError naming the known ones otherwise)."""
    if name not in WORLD_MODELS:
        world_model_names()
    try:
        return WORLD_MODELS[name]
    except KeyError:
        raise ValueError(f"model must be one of {sorted(WORLD_MODELS)}, got {name!r}") from None


def is_world_model(name: str) -> bool:
    """Whether `name` is a registered configuration (of any world)."""
    return name in WORLD_MODELS or name in world_model_names()


def models_of(world_name: str) -> list[str]:
    """The configurations that model world `world_name`, in the order they were registered."""
    _register_models_of(world_name)
    return [name for name, spec in WORLD_MODELS.items() if spec.world == world_name]


def default_model(world_name: str) -> str:
    """The configuration a command uses for world `world_name` unless told another: the road's "default", another
    world's configuration of its own name."""
    return "default" if world_name == DEFAULT_WORLD else world_name


def caution_for(model: str, overrides: Mapping[str, float] | None = None) -> Caution:
    """Configuration `model`'s own caution with `overrides` (field → value, e.g. from the command line) applied;
    an unknown configuration has none of its own."""
    own = world_model_spec(model).caution if is_world_model(model) else Caution()
    return Caution(**{**own.model_dump(), **(overrides or {})})


register_world_model(
    WorldModelSpec(
        "paper",
        PRESETS["paper"],
        PIXELCNN_PRESETS["paper"],
        Caution(),
        budgets={
            "vqvae": {"epochs": 200, "steps_per_epoch": 200, "threads": 1},
            "pixelcnn": {"epochs": 100, "steps_per_epoch": 500, "threads": 1},
        },
        weights={"vqvae": "vqvae-paper.pt", "pixelcnn": "pixelcnn-paper.pt"},
        description="the paper's: 6 × 6 codes from 512, DMoL decoder, 64 × 8 prior; plans on the argmax alone",
    )
)
register_world_model(
    WorldModelSpec(
        "default",
        PRESETS["default"],
        PIXELCNN_PRESETS["default"],
        # chosen on validation episodes, never the evaluation's (docs/design.md, occupancy and the lane margin)
        Caution(occupancy=0.1, margin=1),
        budgets={
            "vqvae": {"epochs": 8, "steps_per_epoch": 1000},
            "pixelcnn": {"epochs": 100, "steps_per_epoch": 500, "threads": 1},
        },
        weights={"vqvae": "vqvae-default.pt", "pixelcnn": "pixelcnn-default.pt"},
        description="ours: 12 × 12 patch-local codes from 4096, calibrated categorical decoder, 32 × 8 prior, "
        "occupancy 0.1 and a one-pixel lane margin",
    )
)
