"""Training the world model's stages: resumable loops checkpointed every epoch (metrics to CSV), run folders named
by what determines their result, and the code arrays the prior trains on."""

from dynplan.training.codes import build_codes
from dynplan.training.loop import TrainBudget
from dynplan.training.pixelcnn import train_pixelcnn
from dynplan.training.vqvae import train_vqvae

__all__ = ["TrainBudget", "build_codes", "train_pixelcnn", "train_vqvae"]
