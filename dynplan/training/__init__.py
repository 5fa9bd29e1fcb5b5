"""Training the world model's stages: resumable loops checkpointed every epoch (metrics to CSV), run folders named
by what determines their result, and the code arrays the prior trains on."""

from dynplan.lazy import lazy_names

#: Each public name by its module, imported when first used (`dynplan.lazy`).
_PUBLIC = {
    "TrainBudget": "dynplan.training.budget",
    "build_codes": "dynplan.training.codes",
    "train_pixelcnn": "dynplan.training.pixelcnn",
    "train_vqvae": "dynplan.training.vqvae",
}
__getattr__, __dir__ = lazy_names(__name__, _PUBLIC)
__all__ = sorted(_PUBLIC)
