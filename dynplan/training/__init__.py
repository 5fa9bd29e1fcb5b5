"""Training loops for the world model's stages: resumable, checkpointed every epoch, metrics to CSV."""
