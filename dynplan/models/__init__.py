"""The learned world model: the VQ-VAE tokenizer (stage 1) and the conditional PixelCNN prior (stage 2).

`load_vqvae()` returns a trained tokenizer: `encode(frames)` maps uint8 frames (N, H, W) to integer codes
(N, h, w) and `decode(codes)` maps codes back to uint8 mid-point frames on the world's pixel values.
`load_world_model()` returns the learned forward model the planner uses: `predict(observed_frames, k)`.
Checkpoints are read and written by `dynplan.models.checkpoint`.
"""

from dynplan.lazy import lazy_names

#: Each public name by its module, imported when first used (`dynplan.lazy`).
_PUBLIC = {
    "LearnedWorldModel": "dynplan.models.world_model",
    "PRESETS": "dynplan.models.configs",
    "VQVAE": "dynplan.models.vqvae",
    "VQVAEConfig": "dynplan.models.configs",
    "WEIGHTS": "dynplan.models.weights",
    "WORLD_MODELS": "dynplan.models.registry",
    "WorldModelSpec": "dynplan.models.registry",
    "load_vqvae": "dynplan.models.world_model",
    "load_world_model": "dynplan.models.world_model",
    "pretrained_path": "dynplan.models.weights",
    "register_world_model": "dynplan.models.registry",
    "world_model_spec": "dynplan.models.registry",
}
__getattr__, __dir__ = lazy_names(__name__, _PUBLIC)
__all__ = sorted(_PUBLIC)
