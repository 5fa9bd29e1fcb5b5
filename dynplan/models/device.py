"""Where and how a world model computes: the torch device it generates on, and one thread for exact replays."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def one_thread() -> Iterator[None]:
    """Within the block torch runs on one thread: the same sums whatever the caller's threads and batch, so a result
    replays exactly (on two threads a convolution over an odd batch of frames splits its sums otherwise)."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def check_device(name: str) -> str:
    """`name` as torch spells the device, or a ValueError naming it and what is available (the CPU without
    importing torch, so that a command checks its default at once)."""
    if name == "cpu":
        return name
    import torch

    try:
        device = torch.device(name)
    except (RuntimeError, TypeError):
        raise ValueError(f"device must be a torch device such as 'cpu' or 'cuda', got {name!r}") from None
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {name!r}: no CUDA GPU is available here (use 'cpu')")
    if device.type not in ("cpu", "cuda"):
        raise ValueError(f"device must be 'cpu' or 'cuda[:N]', got {name!r}")
    return str(device)
